"""Frames in which one object moves (Chen & Gao sec. 2.2: "fix the lighting and view conditions,
and relocate a single object"): the bake of the rest of the scene, then per frame the object's
occlusion O_j alone.

A bake with ``vary="object"`` (:func:`wavlight.relight.bake.bake`) holds, for the scene without
the moving object: each pixel's transfer T1 = f cos V_rest, its product with the fixed lighting
on coarse texels (``product_leaves``), and the image of that scene converged by an unbiased
render (``static``, S_p). With the object placed anew, a pixel's radiance is

    B_p = E_x[ integral f cos L V_rest (1 - O_j) dw ] = S_p - E_x[ D(x) ],
    D(x) = integral f cos L V_rest O_j dw,

x a camera sample in the pixel. D is what the object takes away; it is estimated per sample
(eq. 12's bidirectional estimator, with the visibility of the rest inside the sampled product:
its noise is O_j's): a direction from the pixel's product T1 x L (the coarse texel by the
hierarchical warp, then inside it the lighting's own resolution) or, with probability 0.1, from
the BSDF; where it meets the object (traced against the object alone, in its own frame, so
nothing is rebuilt per frame) and not the rest, D gets f cos L / p. A sample whose tangent plane
has the object's bounding sphere wholly below it has D = 0 exactly, and a direction that misses
the sphere needs no ray.

Pixels whose footprint may see the object itself (the cone of the pixel meets the object's
bounding sphere; decided from the object's place alone, not from random samples, so that the
choice does not bias the estimate) are rendered in full with ``mis`` (the existing strategy,
:func:`wavlight.strategies.shade_reference`) against the moved scene. Every frame is unbiased:
tests/test_relight_moving.py checks it against ``mis`` of the moved scene.
"""
from __future__ import annotations

import time

import numpy as np

from .. import rng, strategies
from ..camera import camera_rays, project
from ..envmap import Environment
from ..errors import ArgumentError, WavlightError, check_int, check_real
from ..haar.tree import HaarTree
from ..integrator import RenderResult
from ..raytrace import RayTracer
from ..scene import rotation
from ..warp import frame as tangent_frame
from .bake import camera_jitter
from .converge import _scene_of, _TexelLight, mixture_directions

#: Philox streams of a moving-object frame: camera jitter per chunk, direction uniforms, MIS
FRAME_STREAM, DIRECTION_STREAM, MIS_STREAM = 11, 12, 13
#: pixels per chunk (memory stays bounded at any size)
CHUNK_PIXELS = 1 << 14
#: the per-pixel product trees kept from frame to frame (device memory, about 1.4 kB a pixel
#: at 16 x 16 texels: a 256 x 256 image's whole)
TREE_CACHE_BYTES = 256 << 20
DEFENSIVE = 0.1


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


class MovingObject:
    """The moving object's frames for one bake: the scene (checked against the bake), the tracers
    of the rest and of the object (in its own frame), the lighting, and the per-pixel products."""

    def __init__(self, transfer, scene=None):
        if transfer.header.get("vary") != "object":
            raise WavlightError(f"{transfer.path}: this bake varies the {transfer.header.get('vary', 'lighting')}, "
                                "not an object")
        self.transfer = transfer
        self.scene = _scene_of(transfer, scene)
        info = transfer.header["object"]
        self.object = self.scene.find_object(info["index"])
        self.rest = self.scene.without(self.object)
        self.rest_tracer = RayTracer(self.rest.vertices, self.rest.faces, threads=2)
        self.object_tracer = RayTracer(self.object.local, self.object.faces, threads=2)
        self.center, self.radius = np.asarray(info["center"], np.float64), float(info["radius"])
        env = transfer.environment()
        rot = transfer.scene_rotate_y
        self.environment = Environment(env.pixels, 1.0, rot, env.name)   # radiance lookups, turned
        self.m = int(transfer.header["product_levels"])
        self.inside = _TexelLight(env, self.m, rot)
        self.mis = strategies.make("mis")
        self.mis.prepare(self.environment)
        self.static = np.asarray(transfer._s["static"], np.float64)
        self.static_se = np.asarray(transfer._s["static_stderr"], np.float64)
        self.leaves = transfer._s["product_leaves"]
        self._trees, self._tree_bytes = {}, 0
        self._centre_rays = (None, None)

    # -- the object's place
    def placement(self, translate=None, rotate=None):
        """(R (3, 3), T (3,)) of the object at ``translate`` and ``rotate`` [axis, degrees]
        (absolute, replacing its own keys; None keeps them)."""
        where = "relight.moving"
        ob = self.object
        t = ob.translate if translate is None else check_real(where, "translate", translate, finite=True).reshape(3)
        if rotate is None:
            r = ob.rotate
        else:
            r = check_real(where, "rotate", rotate, finite=True).reshape(-1)
            if r.shape != (4,) or np.linalg.norm(r[:3]) == 0:
                raise ArgumentError(f"{where}: rotate must be [axis x, y, z, degrees] with a non-zero axis")
        return rotation(None if r is None else list(r)), np.asarray(t, np.float64)

    def _object_pixels(self, R, T, width, height):
        """(H, W) bool: the pixels a camera sample of which may see the object: those whose
        footprint's cone meets the object's bounding sphere and lies in the bounding box of one of
        its triangles' projections (grown by a pixel), a test of the place alone, conservative
        (every pixel one of whose samples could hit the object is in it)."""
        near = self._sphere_pixels(R, T, width, height)
        xy, depth = project(self.scene.camera, self.object.local @ R.T + T, width, height)
        if not near.any() or not np.all(depth > 0):   # a vertex behind the eye: the cone test alone
            return near
        # each vertex's pixel (clipped just outside the image: the boxes' overlaps stay the same)
        cell = np.floor(np.clip(xy, -2.0, [width + 2.0, height + 2.0])).astype(np.int64)
        f = self.object.faces
        a, b, c = cell[f[:, 0]], cell[f[:, 1]], cell[f[:, 2]]
        lo = np.minimum(np.minimum(a, b), c) - 1
        hi = np.maximum(np.maximum(a, b), c) + 1
        keep = (hi[:, 0] >= 0) & (hi[:, 1] >= 0) & (lo[:, 0] < width) & (lo[:, 1] < height)
        lo = np.maximum(lo[keep], 0)
        hi = np.minimum(hi[keep], [width - 1, height - 1])
        # the union of the boxes: +1 at each box's first corner, -1 past its edges, summed up
        row, col = np.concatenate([lo[:, 1], lo[:, 1], hi[:, 1] + 1, hi[:, 1] + 1]), \
            np.concatenate([lo[:, 0], hi[:, 0] + 1, lo[:, 0], hi[:, 0] + 1])
        sign = np.repeat([1.0, -1.0, -1.0, 1.0], len(lo))
        marks = np.bincount(row * (width + 1) + col, sign, (height + 1) * (width + 1)).reshape(height + 1, width + 1)
        boxes = marks.cumsum(0).cumsum(1)[:height, :width] > 0.5
        return near & boxes

    def _sphere_pixels(self, R, T, width, height):
        """(H, W) bool: the pixels whose footprint's cone meets the object's bounding sphere."""
        cam = self.scene.camera
        c = R @ self.center + T
        if self._centre_rays[0] != (width, height):   # the pixels' centre rays, kept for the next frames
            py, px = np.mgrid[0:height, 0:width]
            d = camera_rays(self.scene, px.ravel(), py.ravel(), np.full((width * height, 2), 0.5), width, height)[1]
            self._centre_rays = ((width, height), d.astype(np.float64))
        d = self._centre_rays[1]
        to = c - np.asarray(cam.eye, np.float64)
        dist = np.linalg.norm(to)
        if dist <= self.radius:
            return np.ones((height, width), bool)
        half = np.arcsin(min(self.radius / dist, 1.0))
        # the pixel's own half-diagonal angle, from the vertical field of view
        pixel = np.radians(cam.fov_y) / height * 0.75
        angle = np.arccos(np.clip(d @ (to / dist), -1.0, 1.0))
        return (angle <= half + pixel).reshape(height, width)

    def _trace_object(self, R, T, origins, dirs, closest=False):
        """Rays against the object alone, in its own frame (rigid: distances are kept)."""
        o = (np.asarray(origins, np.float64) - T) @ R
        d = np.asarray(dirs, np.float64) @ R
        if closest:
            return self.object_tracer.intersect(o.astype(np.float32), d.astype(np.float32))
        return self.object_tracer.occluded(o.astype(np.float32), d.astype(np.float32))

    # -- a frame
    def frame(self, translate=None, rotate=None, spp: int = 4, seed: int = 0) -> RenderResult:
        """The unbiased frame with the object at its new place (module docstring)."""
        spp = check_int("relight.moving", "spp", spp, 1, 1 << 16)
        seed = check_int("relight.moving", "seed", seed, 0, 2 ** 62)
        R, T = self.placement(translate, rotate)
        t0 = time.perf_counter()
        tr = self.transfer
        width, height = tr.width, tr.height
        touched = self._object_pixels(R, T, width, height).reshape(-1)
        image = np.zeros((width * height, 3))
        error = np.zeros((width * height, 3))
        rays = 0
        for chunk, first in enumerate(range(0, width * height, CHUNK_PIXELS)):   # chunks of pixels
            pixels = np.arange(first, min(first + CHUNK_PIXELS, width * height))
            value, mean_var, n_rays = self._chunk(R, T, pixels, touched[pixels], spp, seed, chunk)
            rays += n_rays
            mean = value.mean(1)
            var = value.var(1, ddof=1) / spp if spp > 1 else np.full_like(mean, np.inf)
            image[pixels], error[pixels] = mean, np.sqrt(var + mean_var)
        seconds = time.perf_counter() - t0
        stats = {"spp": spp, "seed": seed, "width": width, "height": height, "render_seconds": round(seconds, 4),
                 "rays": rays, "object_pixels": int(touched.sum()),
                 "translate": T.tolist(), "estimator": "static image minus the object's occlusion D"}
        return RenderResult(image.reshape(height, width, 3).astype(np.float32),
                            error.reshape(height, width, 3).astype(np.float32), stats)

    def _chunk(self, R, T, pixels, touched, spp, seed, chunk):
        """(values (P, S, 3) per sample, the variance each pixel's static part adds (P, 3), rays)."""
        tr, scene = self.transfer, self.scene
        width, height = tr.width, tr.height
        P = len(pixels)
        px, py = np.repeat(pixels % width, spp), np.repeat(pixels // width, spp)
        eye, d = camera_rays(scene, px, py, camera_jitter(seed, FRAME_STREAM * 65536 + chunk, P, spp), width, height)
        d64 = d.astype(np.float64)
        prim_r, t_r = self.rest_tracer.intersect(eye, d)
        rays = len(d)
        full = np.repeat(touched, spp)                       # samples of pixels rendered in full
        value = np.zeros((P * spp, 3))
        # pixels that may see the object: mis against the moved scene
        if full.any():
            idx = np.flatnonzero(full)
            value[idx], r = self._full(R, T, eye[idx], d[idx], prim_r[idx], t_r[idx], seed, chunk)
            rays += r
        # the others: S_p minus the object's occlusion D at each sample
        rest = np.flatnonzero(~full & (prim_r >= 0))
        mean_var = np.zeros((P, 3))
        if len(rest):
            D, r = self._occlusion(R, T, eye, d64, prim_r, t_r, rest, pixels, spp, seed, chunk)
            rays += r
            value[rest] = -D
        static = np.repeat(self.static.reshape(-1, 3)[pixels], spp, axis=0)
        value[~full] += static[~full]
        mean_var[~touched] = self.static_se.reshape(-1, 3)[pixels][~touched] ** 2
        return value.reshape(P, spp, 3), mean_var, rays

    def _product_trees(self, chunk, pixels):
        """The HaarTree of the chunk's pixels' products T1 x L and each pixel's total: they do not
        depend on the object's place, so they are kept for the next frames while they fit in
        TREE_CACHE_BYTES (larger images rebuild the chunks beyond)."""
        if chunk in self._trees:
            return self._trees[chunk]
        leaves = np.asarray(self.leaves[pixels], np.float32).reshape(len(pixels), 1 << self.m, 1 << self.m)
        made = HaarTree(np.maximum(leaves, 0.0)), leaves.reshape(len(pixels), -1).sum(1)
        size = 4 * made[0].n_trees * made[0].stride
        if self._tree_bytes + size <= TREE_CACHE_BYTES:
            self._trees[chunk] = made
            self._tree_bytes += size
        return made

    def _occlusion(self, R, T, eye, d, prim, t, rest, pixels, spp, seed, chunk):
        """D (len(rest), 3) at the samples ``rest`` (which hit the rest of the scene)."""
        sc = self.rest
        n_all, p_all, origin_all = self.rest_tracer.surface(sc.camera.eye, d[rest].astype(np.float32),
                                                            t[rest], prim[rest])
        nrm, x = n_all.astype(np.float64), p_all.astype(np.float64)
        center = R @ self.center + T
        to = center - x
        dist = np.linalg.norm(to, axis=1)
        # the object's bounding sphere wholly below the tangent plane: D = 0 exactly
        live = np.flatnonzero(np.einsum("ij,ij->i", to, nrm) > -self.radius)
        D = np.zeros((len(rest), 3))
        rays = 0
        if not len(live):
            return D, rays
        s_ax, t_ax = tangent_frame(nrm[live])
        n = nrm[live]
        wo_w = -d[rest][live]
        wo = np.stack([np.einsum("ij,ij->i", wo_w, a) for a in (s_ax, t_ax, n)], 1)
        mat = sc.face_material[prim[rest][live]]
        kind, param, albedo = sc.material_kind[mat], sc.material_param[mat], sc.material_albedo[mat]
        # each sample's pixel's product tree (chunk-local trees, one per pixel)
        local_pixel = (rest[live] // spp)
        trees, pixel_mass = self._product_trees(chunk, pixels)
        mass = pixel_mass[local_pixel]
        u = rng.uniforms(seed, FRAME_STREAM * 65536 + chunk, DIRECTION_STREAM, 0, len(pixels) * spp)
        alpha = np.where(mass > 0, DEFENSIVE, 1.0)
        direction, weight = mixture_directions(trees, self.inside, u, rest[live], spp, mass > 0, alpha, kind, param,
                                               wo, (s_ax, t_ax, n))
        # only directions that meet the bounding sphere can meet the object
        tc = np.einsum("ij,ij->i", to[live], direction)
        miss_dist2 = dist[live] ** 2 - tc ** 2
        meets = (weight > 0) & (tc > -self.radius) & (miss_dist2 <= self.radius ** 2)
        cand = np.flatnonzero(meets)
        origin = origin_all[live]
        if len(cand):
            blocked = self._trace_object(R, T, origin[cand], direction[cand])
            rays += len(cand)
            hit = cand[blocked]
            if len(hit):
                rest_blocked = self.rest_tracer.occluded(origin[hit], direction[hit].astype(np.float32))
                rays += len(hit)
                hit = hit[~rest_blocked]
                radiance = self.environment.eval(direction[hit])
                D[live[hit]] = albedo[hit] * (weight[hit][:, None] * radiance)
        return D, rays

    def _full(self, R, T, eye, d, prim_r, t_r, seed, chunk):
        """mis against the moved scene for samples of pixels that may see the object."""
        scene = self.scene
        prim_o, t_o = self._trace_object(R, T, eye, d, closest=True)
        on_object = (prim_o >= 0) & ((prim_r < 0) | (t_o < t_r))
        on_rest = (prim_r >= 0) & ~on_object
        value = np.zeros((len(d), 3))
        miss = np.flatnonzero(~on_object & ~on_rest)
        value[miss] = self.environment.eval(d[miss].astype(np.float64))
        hits = np.flatnonzero(on_object | on_rest)
        if not len(hits):
            return value, 0
        n = np.zeros((len(hits), 3))
        p = np.asarray(eye, np.float64)[hits] + d[hits].astype(np.float64) * np.where(
            on_object[hits], t_o[hits], t_r[hits])[:, None]
        mats = np.zeros(len(hits), np.int64)
        r_idx, o_idx = np.flatnonzero(on_rest[hits]), np.flatnonzero(on_object[hits])
        if len(r_idx):
            n[r_idx] = self.rest_tracer.face_normals[prim_r[hits][r_idx]]
            mats[r_idx] = self.rest.face_material[prim_r[hits][r_idx]]
        if len(o_idx):
            n[o_idx] = self.object_tracer.face_normals[prim_o[hits][o_idx]] @ R.T
            mats[o_idx] = self.object.material
        dd = d[hits].astype(np.float64)
        n = n * np.where(np.einsum("ij,ij->i", n, dd) > 0, -1.0, 1.0)[:, None]
        s_ax, t_ax = tangent_frame(n)
        wo = np.stack([np.einsum("ij,ij->i", -dd, a) for a in (s_ax, t_ax, n)], 1)
        sp = strategies.ShadingPoints(p, n, s_ax, t_ax, wo, scene.material_kind[mats], scene.material_param[mats],
                                      scene.material_albedo[mats].astype(np.float64), mats)
        u = rng.uniforms(seed, FRAME_STREAM * 65536 + chunk, MIS_STREAM, 0, len(hits)).astype(np.float64)
        wi, val = strategies.shade_reference(self.mis, self.environment, sp, u)
        offset = np.maximum(1e-4 * np.abs(p).max(1), 1e-6 * self.rest_tracer.scale)
        origin = (p + n * offset[:, None]).astype(np.float32)
        total = np.zeros((len(hits), 3))
        rays = 0
        for slot in range(wi.shape[1]):   # the MIS pair, not samples
            live = np.flatnonzero(val[:, slot].max(1) > 0)
            w = wi[live, slot].astype(np.float32)
            blocked = self.rest_tracer.occluded(origin[live], w) | self._trace_object(R, T, origin[live], w)
            rays += 2 * len(live)
            total[live] += val[live, slot] * ~blocked[:, None]
        value[hits] = total
        return value, rays


def moving_frame(transfer, translate=None, rotate=None, spp: int = 4, seed: int = 0, scene=None) -> RenderResult:
    """One unbiased frame of a bake with ``vary="object"`` with the object at ``translate`` and
    ``rotate`` (absolute; None keeps its own): :class:`MovingObject` (made once per call; keep
    one for many frames)."""
    return MovingObject(transfer, scene).frame(translate, rotate, spp, seed)

