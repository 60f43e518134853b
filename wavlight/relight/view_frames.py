"""Frames from a moving camera from precomputed transfer (Chen & Gao sec. 2.2, eq. 6-8, with the
view as the varying factor): the lighting and the objects stay fixed, the camera moves.

    B(x, wo) = integral of L(w) V(x, w) max(cos theta, 0) f_r(x, w, wo) dw = <T1(x), T2>,
    T1(x, w) = L(w) V(x, w) max(cos theta, 0)  (per surface point, baked),
    T2 = f_r(x, ., wo)  (per frame; the albedo factored out: f_r = albedo x shape;
                         plastic's f_r = coat + albedo x base: two walks, :meth:`ViewFrames.lobes`).

T1 is baked on the surface cache (:mod:`wavlight.relight.surface_cache`) by
:mod:`wavlight.relight.view_bake`; :class:`ViewFrames` makes a view bake's frames.

The approximate frame (:meth:`ViewFrames.frame`). Camera rays through the pixel centres (or the
centres of S x S sub-pixels, ``supersample``, their mean the pixel's value) are traced; each hit
has its three cache points and weights, and the product <T1, f_r> is the top-down walk of
:mod:`wavlight.relight.view_walk` (eq. 13, refined where f_r or T1's mass varies). Two modes:

- ``point``: for every cache point k the hits use, B_k = <T1(x_k), f_r(x_k, ., wo_k)> with the
  point's own (area-averaged) normal and wo_k the direction to the eye; a pixel is its albedo
  times the barycentric blend of its three points' B_k. lambert points need only the scaling
  coefficient: B = T^_0 N^2 / pi. One product per point: the fastest. A plastic point walks twice,
  its base B_k and its coat C_k (:mod:`wavlight.relight.view_walk`), and a pixel is a sum_k w_k B_k
  + sum_k w_k C_k (the coat untinted).
- ``pixel``: per ray, B = <sum_k w_k T1(x_k), f_r(., wo) rho> (the walk blends the three points'
  coefficients) with the hit's shading normal n (as ``mis`` shades: the face normal where the
  face is flat) and the pixel's own view direction, so that f_r is the pixel's; with ``tau`` > 0
  the baked cosine at the points' blended normal is turned into n's (the cosine's correction,
  :mod:`wavlight.relight.view_walk`); plastic likewise, a B + C from its two walks.

A ray's value is B times the albedo at its hit: the material's, in a textured scene times its
base-colour texture there (:meth:`ViewFrames.hit_albedo`; on the device ``view_assemble`` with
kernels/texture.h), not the blend of the cache points' albedos, which would blur a texture to
the cache's spacing (docs/decisions/view-bake-textures.md). The unbiased frame shades each
camera sample with the texture at its hit (``converge_shade`` built with the textures).

Pixels whose ray misses see the environment (its nearest texel, :meth:`wavlight.envmap.Environment.eval`;
with ``background="bilinear"`` its filter, with ``background="none"`` 0: the background hidden,
:meth:`~wavlight.envmap.Environment.eval_background`; :meth:`ViewFrames.with_background`).

On the device (backend ``opencl``) a frame after its camera rays is three kernels: ``view_lookup``
(per ray its three cache points and weights, numpy twin :meth:`ViewFrames.hit_points`, and a
flag per cache point used), ``view_product`` over the flagged points (``point`` mode) and
``view_assemble`` (per ray the albedo times the blend of its points' B_k, or the environment's
texel; the numpy frame is its twin); only the flags, the nodes visited and the image come back.
``pixel`` mode reads the lookup's points and weights back and walks per pixel.

Approximate by design: the texels, the cache's
spacing (shadows and highlights are interpolated between points), the compression and the
midpoint rule each leave an error; and one ray per pixel samples facets smaller than a pixel
where ``mis`` integrates over the pixel (benchmarks/relight_view.py measures both modes against
``mis``, with one and with 4 x 4 rays per pixel).

The unbiased frame (:meth:`ViewFrames.converge`, on the device: :mod:`wavlight.relight.view_converge`).
Each pixel's camera samples draw their directions from a defensive mixture: the product T1 x f_r
(visibility inside it: T1 holds V) of the cache at the hit of the pixel's centre ray, on 2^m x 2^m
texels (m = min(n, PRODUCT_LEVELS); the top-left 2^m x 2^m block of T1's coefficients is the
transform of its coarser texels, eq. 13), times f_r averaged over points of each texel for that
hit's normal and view, walked by the hierarchical warp (eq. 17-22), then inside the texel by the lighting's own
luminance at the map's resolution (:class:`wavlight.relight.mixture.TexelLight`); the BSDF; and
the lighting alone (a bright light that the bake's one shadow ray per texel hid from a cache
point's T1 is still found). Every direction is evaluated with the true f_r cos, the radiance and a
shadow ray, and weighted by the mixture's pdf (every technique's pdf, exact); the pixel's product
at the trees' texels is the control variate's known integral: unbiased whatever the cache's
approximations (tests/relight/test_relight_view.py checks it against ``mis``).
"""
from __future__ import annotations

import copy
import dataclasses
import hashlib
import threading
import time
from collections import OrderedDict

import numpy as np

from .. import bsdfs, cl
from ..camera import camera_rays
from ..envmap import Environment
from ..errors import ArgumentError, WavlightError, check_number, check_real
from ..integrator import RenderResult
from ..raytrace import RayTracer
from ..scene import MAX_COORDINATE, Camera
from .converge import PASS_SPP
from .mixture import TexelLight, check_shares, scene_of
from .settings import FRAME, UNBIASED_SPP, WRITTEN_SUPERSAMPLE
from .surface_cache import CREASE_DEGREES, barycentric, lattice_points
from .view_walk import MASS, REFINE, VIEW_BASE, VIEW_COAT, FrameDevice, ViewDevice, lifted_view, product_reference

#: the unbiased frame's product texel levels at most (:mod:`wavlight.relight.view_converge`)
PRODUCT_LEVELS = 4
#: pixels per chunk of a frame (bounded memory)
CHUNK_PIXELS = 1 << 16
#: the approximate frame's modes: a product per cache point or per pixel; :meth:`ViewFrames.frame`'s
#: default is the viewer's
MODES = FRAME["mode"].values
MODE = "point"
#: the pixel mode's cosine correction: a node is refined while the factor rho varies more than this
TAU = FRAME["tau"].default
#: rays per pixel of a frame: at most MAX_SUPERSAMPLE^2
MAX_SUPERSAMPLE = FRAME["supersample"].hi


def still_settings(refine: float = REFINE, mass: float = MASS, mode: str = FRAME["mode"].default,
                   supersample=None, tau: float = TAU) -> dict:
    """A written frame's settings (``wavlight frame``; the defaults are its records',
    :data:`wavlight.relight.settings.FRAME`): a product per ray at WRITTEN_SUPERSAMPLE^2 rays per
    pixel (2.8% from ``mis`` over the rough bunnies' frames, 3.3-3.4% on the bunny), where
    :meth:`ViewFrames.frame`'s defaults (``point``, one ray) are the viewer's
    (docs/decisions/view-point-mode.md). ``supersample`` None: WRITTEN_SUPERSAMPLE in ``pixel``
    mode, 1 in ``point`` mode (more rays do not sharpen its blend). Checked by :meth:`ViewFrames.frame`."""
    if supersample is None:
        supersample = WRITTEN_SUPERSAMPLE if mode == "pixel" else 1
    return {"refine": refine, "mass": mass, "mode": mode, "supersample": supersample, "tau": tau}


#: a written frame's settings where none are given
STILL = still_settings()


def check_camera(where: str, eye, target, up, fov) -> Camera:
    """A frame's camera: finite eye and target within the ray tracer's range, apart, the view not
    along ``up``, 0 < fov < 180."""
    eye = check_real(where, "eye", eye, finite=True).reshape(-1).astype(np.float64)
    target = check_real(where, "target", target, finite=True).reshape(-1).astype(np.float64)
    if eye.shape != (3,) or target.shape != (3,):
        raise ArgumentError(f"{where}: eye and target must be three numbers each")
    if max(np.abs(eye).max(), np.abs(target).max()) > MAX_COORDINATE:
        raise ArgumentError(f"{where}: eye and target must be within the ray tracer's range (|x| <= "
                            f"{MAX_COORDINATE:g}), got {eye.tolist()} and {target.tolist()}")
    fov = FRAME["fov"].check(fov, where)
    fwd = target - eye
    if not np.linalg.norm(fwd) > 1e-9 * max(1.0, float(np.abs(eye).max())):
        raise ArgumentError(f"{where}: the eye {eye.tolist()} and the target are the same point")
    up = np.asarray(up, np.float64)
    if np.linalg.norm(np.cross(fwd / np.linalg.norm(fwd), up / np.linalg.norm(up))) < 1e-6:
        raise ArgumentError(f"{where}: the view from {eye.tolist()} to {target.tolist()} is along the camera's up")
    return Camera(eye, target, up, float(fov))


def orbit_eyes(eye, target, frames: int) -> np.ndarray:
    """(frames, 3): the eye turned about the vertical axis through the target by 360 i / frames."""
    eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
    a = 2 * np.pi * np.arange(frames) / frames
    rel = eye - target
    c, s = np.cos(a), np.sin(a)
    return target + np.stack([c * rel[0] + s * rel[2], np.full(frames, rel[1]), -s * rel[0] + c * rel[2]], 1)


#: the lighting inside the product's texels of the last LIGHTS_KEPT maps, shared by the process's
#: ViewFrames (:func:`texel_light`): made from a 1k map it takes 0.2-0.4 CPU s, a new ViewFrames
#: of the same map would make it again
LIGHTS_KEPT = 2
_LIGHTS = OrderedDict()
_LIGHTS_LOCK = threading.Lock()


def texel_light(environment, levels: int):
    """The lighting of ``environment`` (its pixels turned by its rotate_y) inside 2^levels x 2^levels
    texels (:class:`wavlight.relight.mixture.TexelLight`), kept for the next ViewFrames of the same
    map: keyed by the pixels' content (a hash of their bytes), the rotation and the levels, the
    last LIGHTS_KEPT of them (read-only once made: frames of several threads share one).
    Returns it and whether it was kept (made before by this process)."""
    pixels = np.ascontiguousarray(environment.pixels)
    key = (hashlib.blake2b(pixels.view(np.uint8).reshape(-1), digest_size=16).digest(), pixels.shape,
           pixels.dtype.str, float(environment.rotate_y), int(levels))
    with _LIGHTS_LOCK:
        found = _LIGHTS.get(key)
        if found is not None:
            _LIGHTS.move_to_end(key)
            return found, True
    inside = TexelLight(Environment(pixels, 1.0, 0.0, environment.name), int(levels), environment.rotate_y)
    with _LIGHTS_LOCK:
        _LIGHTS[key] = inside
        while len(_LIGHTS) > LIGHTS_KEPT:
            _LIGHTS.popitem(last=False)
    return inside, False


class ViewFrames:
    """The frames of a view bake: its scene (reloaded and checked against the bake), tracer,
    cache and device entries."""

    def __init__(self, transfer, scene=None, background: str = FRAME["background"].default):
        background = FRAME["background"].check(background, "relight.ViewFrames")
        varies = transfer.varies
        if varies != "view":
            raise WavlightError(f"{transfer.path}: this bake varies the {'lighting' if varies == 'lighting' else 'object'}"
                                f", not the view")
        self.transfer = transfer
        self.scene = scene_of(transfer, scene)
        self.tracer = RayTracer(self.scene.vertices, self.scene.faces, threads=2, normals=self.scene.normals,
                                normal_faces=self.scene.normal_faces)
        s = transfer._s
        self.position = np.asarray(s["view_position"], np.float64)
        self.normal = np.asarray(s["view_normal"], np.float64)
        self.material = np.asarray(s["view_material"], np.int64)
        self.face_k, self.face_base = np.asarray(s["view_face_k"]), np.asarray(s["view_face_base"])
        self.lattice = np.asarray(s["view_lattice"])
        if len(self.face_k) != len(self.scene.faces):
            raise WavlightError(f"{transfer.path}: its cache holds {len(self.face_k)} faces, the scene "
                                f"{len(self.scene.faces)}")
        if len(self.material) and self.material.max() >= len(self.scene.materials):
            raise WavlightError(f"{transfer.path}: its cache points' materials go up to {self.material.max()}, the "
                                f"scene has {len(self.scene.materials)}")
        self.n = transfer.n_levels
        self.kind_of = self.scene.material_kind
        self.param_of = self.scene.material_param
        self.albedo_of = self.scene.material_albedo.astype(np.float64)
        #: base-colour textures: the frames take the albedo at the hit (:meth:`hit_albedo`)
        self.textured = bool(self.scene.textured)
        #: plastic's rows (materials, PLASTIC_STRIDE) float32 (zeros for the other kinds)
        self.plastic_table = self.scene.material_table
        fn = np.asarray(self.tracer.face_normals, np.float64)
        self.face_normal = fn / np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        self.face_normal32 = self.face_normal.astype(np.float32)
        self.normal32 = self.normal.astype(np.float32)
        #: the lighting, and what camera rays that miss see (``background``: nearest, bilinear or none)
        self.environment = self.scene.environment.with_background(background)
        self._device = None
        self._frame_device = None
        self._centres = {}
        self._inside = None
        self._others = {}
        #: whether the lighting inside the texels came from the process's kept ones (:func:`texel_light`)
        self.lighting_kept = None

    def with_background(self, background: str) -> "ViewFrames":
        """These frames with camera rays that miss seeing ``background`` (:data:`wavlight.options.BACKGROUND`;
        the viewer's hidden background is ``none``): made once and kept, sharing the scene, the
        tracer and the device entries; only the assembly's program (its ``BACKGROUND_MODE``) and
        the converge frames are their own."""
        background = FRAME["background"].check(background, "relight.ViewFrames")
        if background == self.environment.background:
            return self
        other = self._others.get(background)
        if other is None:
            if self._device is None:
                self._device = ViewDevice(self.transfer)
            other = copy.copy(self)
            other.environment = self.environment.with_background(background)
            other._frame_device, other._centres, other._others = None, {}, {}
            self._others[background] = other
        return other

    # -- cameras
    def camera(self, eye=None, target=None, fov=None):
        cam = self.scene.camera
        return check_camera("relight.view", cam.eye if eye is None else eye, cam.target if target is None else target,
                            cam.up, cam.fov_y if fov is None else fov)

    def size(self, width=None, height=None) -> tuple:
        """(width, height) of a frame: those given, checked (FRAME's ranges), else the bake's."""
        w = FRAME["width"].check(self.transfer.width if width is None else width, "relight.view")
        h = FRAME["height"].check(self.transfer.height if height is None else height, "relight.view")
        return w, h

    def _pixel_centres(self, width, first, count, supersample: int = 1):
        """Columns, rows (float32) and offsets of the rays of pixels first .. first + count - 1
        of a frame ``width`` wide: the pixel's centre, or the centres of its S x S sub-pixels
        (S = ``supersample``; a pixel's S^2 rays adjacent), the last chunk's kept: the next frame's."""
        key = (width, first, count, supersample)
        if key not in self._centres:
            sub = supersample * supersample
            kept = self._centres.get(("rays", count, supersample))
            if kept is None:   # the chunk's pixels (from 0) and sub-pixel offsets, shared by its chunks
                k = np.tile(np.arange(sub), count)
                offsets = np.stack([(k % supersample + 0.5) / supersample, (k // supersample + 0.5) / supersample], 1)
                kept = (np.repeat(np.arange(count), sub), offsets.astype(np.float32))
            pix = kept[0] + first
            self._centres = {key: ((pix % width).astype(np.float32), (pix // width).astype(np.float32), kept[1]),
                             ("rays", count, supersample): kept}
        return self._centres[key]

    # -- the cache at hits
    def hit_points(self, eye, d, prim, t, uv=None):
        """The cache points (M, 3) and normalized weights (M, 3) of hits (prim >= 0) (at barycentric
        ``uv`` if given, else from the hit points), with 0 where a point is not usable (another
        side of the face, a crease); and the face normals."""
        if uv is None:
            p = np.asarray(eye, np.float64) + d.astype(np.float64) * t.astype(np.float64)[:, None]
            uv = barycentric(self.scene.vertices, self.scene.faces, prim, p)
        ids, w = lattice_points(self.face_k, self.face_base, self.lattice, prim, *uv)
        fn = self.face_normal32[prim]
        front = np.einsum("ij,ij->i", fn, d) < 0
        compat = np.einsum("ijk,ik->ij", self.normal32[ids], fn) >= np.float32(np.cos(np.radians(CREASE_DEGREES)))
        w = w * (compat & front[:, None])
        total = w.sum(1, keepdims=True)
        return ids, np.where(total > 0, w / np.where(total > 0, total, 1.0), 0.0), fn

    def hit_albedo(self, prim, u, v) -> np.ndarray:
        """(M, 3) float32: the albedo at hits on faces prim at embree's (u, v): the material's, times
        its base-colour texture there in a textured scene (Scene.albedo_at: the numpy twin of
        ``view_assemble``'s texture lookup, kernels/texture.h)."""
        if not self.textured:
            return self.albedo_of[self.scene.face_material[prim]].astype(np.float32)
        return self.scene.albedo_at(prim, np.asarray(u, np.float32), np.asarray(v, np.float32))

    def shading_normals(self, eye, d, t, prim, u, v, fn):
        """The shading normals (M, 3) float32 of hits at barycentrics (u, v) (RayTracer.hit), turned
        to the side of their face normals ``fn`` as the cache is (a hit on the face's back side has
        no cache); ``fn`` itself where the scene is flat."""
        if not self.tracer.smooth or not len(prim):
            return fn
        n = self.tracer.hit(eye, np.asarray(d, np.float32), np.asarray(t, np.float32), prim, u, v)[0]
        return (n * np.where(np.einsum("ij,ij->i", n, fn) < 0, -1.0, 1.0)[:, None]).astype(np.float32)

    def lobes(self, mat):
        """The walks of items of materials ``mat`` (I,): plastic walks as two items, its lobes
        (f cos = coat + albedo x base, :mod:`wavlight.relight.view_walk`): kinds and parameters
        (I + C,) with each plastic item's base (VIEW_BASE) in its place and its coat (VIEW_COAT,
        parameter alpha) appended, the items the C coat walks repeat (C,), and every walk's row of
        the plastic table (material x PLASTIC_STRIDE)."""
        mat = np.asarray(mat, np.int64)
        kind = np.asarray(self.kind_of[mat], np.int64).copy()
        param = np.asarray(self.param_of[mat], np.float64).copy()
        coat = np.flatnonzero(kind == bsdfs.PLASTIC)
        if not len(coat):
            return kind, param, coat, np.zeros(len(mat), np.int64)
        kind[coat] = VIEW_BASE
        kinds = np.concatenate([kind, np.full(len(coat), VIEW_COAT, np.int64)])
        params = np.concatenate([param, self.plastic_table[mat[coat], 3].astype(np.float64)])
        return kinds, params, coat, np.concatenate([mat, mat[coat]]) * bsdfs.PLASTIC_STRIDE

    def walks(self, points, mat, normal, wo, refine, backend, mass, weights=None, t1_normal=None,
              tau: float = 0.0, queue=None, on_device: bool = False):
        """The walks of items (cache points ``points`` (I,) or (I, 3) with ``weights``) of materials
        ``mat`` (:meth:`lobes`): (B, nodes visited, the items C of plastic, the rows I .. I + C
        of B that hold their coats), B (I + C, 3) on the host, or (with ``on_device``) the
        walk's device buffers."""
        kind, param, coat, rows = self.lobes(mat)
        if len(coat):
            ext = (lambda a: None if a is None else np.concatenate([np.asarray(a), np.asarray(a)[coat]]))
            points, normal, wo, weights, t1_normal = (ext(points), ext(normal), ext(wo), ext(weights),
                                                      ext(t1_normal))
        coat_rows = len(mat) + np.arange(len(coat))
        if backend == "numpy":
            s = self.transfer._s
            table = self.plastic_table[rows // bsdfs.PLASTIC_STRIDE] if len(coat) else None
            B, nodes = product_reference(s["offsets"], s["entry_scale"], s["entry_data"], self.n, points, kind, param,
                                         normal, wo, refine, weights, t1_normal, tau, mass, table)
            return B, nodes, coat, coat_rows
        if self._device is None:
            self._device = ViewDevice(self.transfer)
        call = self._device.walk if on_device else self._device.products
        B, nodes = call(points, kind, param, normal, wo, refine, weights, t1_normal, tau, queue, mass,
                        self.plastic_table, rows)
        return B, nodes, coat, coat_rows

    def _point_items(self, points, eye):
        """The point mode's items: cache points, their materials, normals and view directions
        towards ``eye`` (lifted above the tangent plane)."""
        wo = np.asarray(eye, np.float64) - self.position[points]
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        nrm = self.normal[points]
        return points, self.material[points], nrm, lifted_view(nrm, wo)

    def products(self, points, eye, refine=REFINE, backend="opencl", mass: float = MASS):
        """The walks of cache points seen from ``eye`` (:meth:`walks`): B (K + C, 3), the first K
        rows B_k without the albedo (plastic: its base), the last C plastic's coats C_k; a pixel
        of albedo a blends a B_k + C_k."""
        points, mat, nrm, wo = self._point_items(points, eye)
        return self.walks(points, mat, nrm, wo, refine, backend, mass)

    def pixel_products(self, ids, w, face_normal, d, mat, refine=REFINE, tau: float = TAU, backend="opencl",
                       mass: float = MASS):
        """The walks of pixels (:meth:`walks`: B (M + C, 3), nodes visited, plastic's coats): the
        blend of their cache points ``ids`` (M, 3) with weights ``w`` (M, 3), shaded with the
        normal ``face_normal`` (the hits' shading normals, :meth:`shading_normals`), the view
        direction -d, material ``mat`` and the cosine's correction ``tau``
        (:mod:`wavlight.relight.view_walk`)."""
        n = np.asarray(face_normal, np.float64)
        wo = lifted_view(n, -np.asarray(d, np.float64))
        m = np.einsum("ij,ijk->ik", np.asarray(w, np.float64), self.normal[ids])
        return self.walks(ids, mat, n, wo, refine, backend, mass, w, m, tau)

    def frame(self, eye=None, target=None, fov=None, width=None, height=None, refine: float = REFINE,
              backend: str = "opencl", mode: str = MODE, tau: float = TAU, mass: float = MASS,
              supersample: int = 1, background=None):
        """The approximate frame (H, W, 3) float32 seen from ``eye`` towards ``target`` (defaults:
        the scene's camera) and its timings (module docstring): ``mode`` "point" (a product per
        cache point, blended per pixel) or "pixel" (a product per pixel, of its points' blended T1
        with its shading normal, view direction and the cosine corrected within ``tau``); ``refine``
        and ``mass`` set where the walk stops (:mod:`wavlight.relight.view_walk`); ``supersample`` S
        traces S x S rays per pixel (its sub-pixels' centres) and takes their mean (``mis``
        integrates over the pixel, and a mesh's facets can be smaller than a pixel); ``background``
        (None: these frames') what rays that miss see (:meth:`with_background`)."""
        if background is not None and background != self.environment.background:
            return self.with_background(background).frame(eye, target, fov, width, height, refine, backend, mode,
                                                          tau, mass, supersample)
        where = "relight.view"
        refine, mass = FRAME["refine"].check(refine, where), FRAME["mass"].check(mass, where)
        if backend not in ("opencl", "numpy"):
            raise ArgumentError(f"relight.view: backend must be opencl or numpy, got {backend!r}")
        mode, tau = FRAME["mode"].check(mode, where), FRAME["tau"].check(tau, where)
        supersample = FRAME["supersample"].check(supersample, where)
        cam = self.camera(eye, target, fov)
        width, height = self.size(width, height)
        sub = supersample * supersample
        t0 = time.perf_counter()
        scene = dataclasses.replace(self.scene, camera=cam)
        count = width * height
        image = (np.empty if backend == "opencl" else np.zeros)((count, 3), np.float32)   # the device writes all
        timing = {"rays_seconds": 0.0, "lookup_seconds": 0.0, "product_seconds": 0.0, "assembly_seconds": 0.0}
        products, visited = 0, 0
        on_device = backend == "opencl"
        if on_device:
            queue = cl.thread_queue()
            if self._device is None:
                self._device = ViewDevice(self.transfer)
            if self._frame_device is None:
                self._frame_device = FrameDevice(self, self._device)
        step = max(1, CHUNK_PIXELS * 4 // sub)
        for first in range(0, count, step):   # chunks of pixels (bounded memory)
            ta = time.perf_counter()
            chunk = min(step, count - first)
            eye_a, d = camera_rays(scene, *self._pixel_centres(width, first, chunk, supersample), width, height)
            pix = np.arange(chunk * sub)   # the chunk's rays
            rays = image[first:first + chunk] if sub == 1 else \
                (np.empty if on_device else np.zeros)((len(pix), 3), np.float32)
            prim, t, u, v = self.tracer.intersect_uv(eye_a, d)
            tb = time.perf_counter()
            if on_device:
                # the cache lookup on the device; in point mode the walks and the assembly too
                fd = self._frame_device
                ids_b, w_b, prim_b, dir_b, points = fd.lookup(prim, u, v, d, queue)
            if mode == "pixel" or not on_device:
                hit = np.flatnonzero(prim >= 0)
                if on_device:
                    ids = cl.read(ids_b, (len(pix), 3), np.uint32, queue)[hit].astype(np.int64)
                    w = cl.read(w_b, (len(pix), 3), np.float32, queue)[hit].astype(np.float64)
                    fn = self.face_normal32[prim[hit]]
                else:
                    ids, w, fn = self.hit_points(cam.eye, d[hit], prim[hit], t[hit], (u[hit], v[hit]))
                mat = self.scene.face_material[prim[hit]]
                fn = self.shading_normals(cam.eye, d[hit], t[hit], prim[hit], u[hit], v[hit], fn)
            if mode == "point":
                if not on_device:
                    used = np.zeros(len(self.position), bool)
                    used[ids[w > 0]] = True
                    points = np.flatnonzero(used)
                tc = time.perf_counter()
                if on_device:
                    if len(points):
                        pts, pm, nrm, wo = self._point_items(points, cam.eye)
                        B_b, visited_b, coat, coat_rows = self.walks(pts, pm, nrm, wo, refine, backend, mass,
                                                                     queue=queue, on_device=True)
                        nodes = cl.read(visited_b, (len(points) + len(coat),), np.uint32, queue)
                        coat = (points[coat], coat_rows)
                    else:
                        B_b, nodes, coat = cl.scratch("view_walk_out", 12), np.zeros(0, np.uint32), None
                    td = time.perf_counter()
                    fd.assemble(len(pix), prim_b, ids_b, w_b, dir_b, points, B_b, queue, rays, coat, uv=(u, v))
                else:
                    B, nodes, coat, coat_rows = self.products(points, cam.eye, refine, backend, mass)
                    td = time.perf_counter()
                    # a point of weight 0 (or none shaded at all: only back faces seen) reads the zero row
                    at = np.full(len(self.position), len(points), np.int64)
                    at[points] = np.arange(len(points))
                    B = np.asarray(B, np.float32).reshape(-1, 3)
                    rows = np.concatenate([B[:len(points)], np.zeros((1, 3), np.float32)])
                    blend = np.einsum("ij,ijc->ic", w.astype(np.float32), rows[at[ids]])
                    coats = np.zeros_like(rows)
                    coats[coat] = B[coat_rows]
                    rays[pix[hit]] = blend * self.hit_albedo(prim[hit], u[hit], v[hit]) + \
                        np.einsum("ij,ijc->ic", w.astype(np.float32), coats[at[ids]])
                shaded = len(points)
            else:
                ok = np.flatnonzero(w.sum(1) > 0)
                tc = time.perf_counter()
                B, nodes, coat, coat_rows = self.pixel_products(ids[ok], w[ok], fn[ok], d[hit][ok], mat[ok], refine,
                                                                tau, backend, mass)
                B = np.asarray(B, np.float32)
                coats = np.zeros((len(ok), 3), np.float32)
                coats[coat] = B[coat_rows]
                B = B[:len(ok)]
                td = time.perf_counter()
                if on_device:   # the environment where rays miss (no point's row: 0 on hits)
                    fd.assemble(len(pix), prim_b, ids_b, w_b, dir_b, np.zeros(0, np.int64),
                                cl.scratch("view_walk_out", 12), queue, rays, uv=(u, v))
                at = hit[ok]
                rays[pix[at]] = B * self.hit_albedo(prim[at], u[at], v[at]) + coats
                shaded = len(ok)
            if not on_device:
                miss = np.flatnonzero(prim < 0)
                rays[pix[miss]] = self.environment.eval_background(d[miss].astype(np.float64))
            if sub > 1:
                image[first:first + chunk] = rays.reshape(chunk, sub, 3).mean(1)
            te = time.perf_counter()
            products += shaded
            visited += int(np.sum(nodes, dtype=np.int64))
            for key, dt in (("rays_seconds", tb - ta), ("lookup_seconds", tc - tb), ("product_seconds", td - tc),
                            ("assembly_seconds", te - td)):
                timing[key] += dt
        seconds = time.perf_counter() - t0
        stats = {"frame_seconds": seconds, **timing, "width": width, "height": height, "eye": cam.eye.tolist(),
                 "target": cam.target.tolist(), "fov": cam.fov_y, "mode": mode, "tau": tau,
                 "items": "cache points" if mode == "point" else "rays",
                 "cache_points_shaded": products, "nodes_per_point": round(visited / max(products, 1), 2),
                 "refine": refine, "mass": mass, "supersample": supersample}
        return image.reshape(height, width, 3), stats

    # -- the unbiased frame
    def _texel_light(self):
        if self._inside is None:
            self._inside, self.lighting_kept = texel_light(self.environment, min(self.n, PRODUCT_LEVELS))
        return self._inside

    def converge(self, eye=None, target=None, fov=None, width=None, height=None, spp: int = UNBIASED_SPP,
                 seed: int = FRAME["seed"].default, slots=None, defensive=None, threads=None,
                 progress=None, light=None, control: bool = True, backend: str = "opencl", candidates=None,
                 coherence=None, background=None) -> RenderResult:
        """The unbiased frame from ``eye`` (module docstring; kernels and kept trees:
        :mod:`wavlight.relight.view_converge`, whose SLOTS, DEFENSIVE, LIGHT_SHARE, CANDIDATES
        and COHERENCE are the defaults; ``control``: the control variate; ``backend="numpy"``
        the kernels' numpy twins): image, per-pixel standard error, stats; ``setup_seconds`` the
        device tables made by this call (the first), ``frame_seconds`` that plus the frame's;
        ``background`` (None: these frames') what samples that miss see (:meth:`with_background`)."""
        from . import view_converge as vc

        if background is not None and background != self.environment.background:
            return self.with_background(background).converge(eye, target, fov, width, height, spp, seed, slots,
                                                             defensive, threads, progress, light, control, backend,
                                                             candidates, coherence)

        where = "relight.view"
        spp, seed = FRAME["spp"].check(spp, where), FRAME["seed"].check(seed, where)
        slots = vc.SLOTS if slots is None else slots
        defensive = vc.DEFENSIVE if defensive is None else defensive
        light = vc.LIGHT_SHARE if light is None else light
        candidates = vc.CANDIDATES if candidates is None else candidates
        coherence = check_number(where, "coherence", vc.COHERENCE if coherence is None else coherence, 0.0)
        defensive, light = check_shares(where, defensive, light)
        cam = self.camera(eye, target, fov)
        width, height = self.size(width, height)
        scene = dataclasses.replace(self.scene, camera=cam)
        t0 = time.perf_counter()
        inside = self._texel_light()
        if backend == "opencl":   # the entries and the lookup's tables, shared with the approximate frame
            if self._device is None:
                self._device = ViewDevice(self.transfer)
            if self._frame_device is None:
                self._frame_device = FrameDevice(self, self._device)
        frames = vc.converger(self, inside, self._device, self._frame_device, backend, threads)
        setup = time.perf_counter() - t0
        result = frames.frame(scene, width, height, spp, seed, slots, defensive, light, control, PASS_SPP, progress,
                              candidates, coherence)
        result.stats["setup_seconds"] = round(setup, 4)
        result.stats["frame_seconds"] = round(setup + result.stats["render_seconds"], 4)
        result.stats["lighting_kept"] = self.lighting_kept
        return result
