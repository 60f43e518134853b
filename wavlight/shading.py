"""Shading on the OpenCL device: kernels/shade.cl.

:class:`KernelShader` uploads the environment (texels, rotation), the light tree,
the material table and the face normals once, then shades each batch of camera rays
with one launch of the ``shade_rays`` kernel (eight rays per work-item): misses see
the environment; each hit gets its shading frame (the shading normal interpolated at embree's
barycentrics, the geometric normal for the shadow rays' origin and for which directions may
carry light: docs/decisions/shading-normals.md) and, per strategy sample (two for
MIS; the light or product sample walks its tree in the kernel), a direction, its
unoccluded estimate and the shadow ray's origin. Its numpy twin is
:func:`shade_rays_reference` around :func:`wavlight.strategies.shade_reference`;
:class:`NumpyShader` wraps that twin behind the same calls, for tests, for
``backend="numpy"`` and for the numpy-only strategies.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import bsdfs, camera, cl, raytrace, rng, strategies, textures, warp

_WARMED = set()  # shade programs already launched in this process


def material_table(scene) -> np.ndarray:
    """The scene's plastic table (Scene.material_table), float32 (materials, bsdfs.PLASTIC_STRIDE);
    zeros for a scene-like record without one (a record of materials without plastic)."""
    table = getattr(scene, "material_table", None)
    if table is None:
        table = np.zeros((len(scene.material_kind), bsdfs.PLASTIC_STRIDE), np.float32)
    return np.asarray(table, np.float32)


class ShadedRays(NamedTuple):
    """Camera rays after shading, all float32 (float64 from the numpy twin).

    direct (3, N): the radiance the camera sees directly (the environment) for misses; for
    hits the part of their estimate that needs no shadow ray (the wavelet resampling
    estimator's control variate, :func:`strategies.ris_shade_reference`; else zero); origin (N, 3): shadow-ray origins (undefined for misses); wi (N, S, 3):
    the S sampled directions; value (S, 3, N): their unoccluded estimates (zero for misses).
    """

    direct: np.ndarray
    origin: np.ndarray
    wi: np.ndarray
    value: np.ndarray


class KernelShader:
    """The shade kernels. ``shade_rays`` (the renderer's) needs ``tracer`` for its face normals
    and shadow-ray offset; calling the shader shades points given directly."""

    def __init__(self, scene, strategy: strategies.Strategy, tracer=None):
        env = scene.environment
        self.strategy = strategy
        texels = np.zeros((env.height * env.width, 4), np.float32)
        texels[:, :3] = env.pixels.reshape(-1, 3)
        self.env_size = (np.int32(env.width), np.int32(env.height))
        self.texels = cl.to_device(texels)
        self.rot = cl.to_device(env.map_from_world.astype(np.float32).ravel())
        light = getattr(strategy, "light", strategy if isinstance(strategy, strategies.LightStrategy) else None)
        trees = getattr(strategy, "trees", None)   # wavelet: its light trees; the others: the light tree
        trees = trees if trees is not None else getattr(light, "tree", None)
        if trees is not None:
            self.tree, self.levels = trees.buffer, np.int32(trees.n_levels)
        else:
            self.tree, self.levels = cl.to_device(np.zeros(1, np.float32)), np.int32(0)
        self.kind = cl.to_device(scene.material_kind.astype(np.int32))
        self.param = cl.to_device(scene.material_param.astype(np.float32))
        alb = np.zeros((len(scene.materials), 4), np.float32)
        alb[:, :3] = scene.material_albedo
        self.albedo = cl.to_device(alb)
        self.table = cl.to_device(material_table(scene).ravel())   # the plastic rows (kernels/bsdf.h)
        kappa = getattr(strategy, "kappa", np.zeros(len(scene.materials)))
        levels = np.asarray(getattr(strategy, "levels", np.zeros(len(scene.materials), np.int32)), np.int32)
        self.kappa = cl.to_device(np.asarray(kappa, np.float32))
        shapes = np.asarray(getattr(strategy, "shapes", np.zeros(len(scene.materials), np.int32)), np.int32)
        tree_of = np.asarray(getattr(strategy, "tree_index", np.zeros(len(scene.materials), np.int32)), np.int32)
        # depth + 256 lobe shape + 65536 light tree (kernels/product.h make_lobe decodes them)
        self.levels_per_material = cl.to_device(levels + 256 * shapes + 65536 * tree_of)
        depth = int(max(np.max(levels, initial=0), 0))
        kinds = int(np.bitwise_or.reduce(1 << np.asarray(scene.material_kind, np.int64), initial=0)) or 1
        plastic = bool(kinds & (1 << bsdfs.PLASTIC))
        sizes = {}   # the walks' compile-time sizes: light tree depth; product depth and lobe shapes
        self.slots = 2   # directions (shadow rays) per shading sample: 4 for the resampling estimator's option
        if strategy.name in ("light", "mis", "mis_comp", "wavelet"):
            sizes["N_LEVELS"] = int(self.levels)
        if strategy.name == "wavelet":
            lobe_shapes = int(np.bitwise_or.reduce(1 << shapes, initial=0))
            if plastic:   # plastic's diffuse lobe: the lambert shape at its own depth (kernels/shade.cl)
                diffuse = int(strategy.plastic_diffuse_levels)
                lobe_shapes |= 1 << bsdfs.LAMBERT
                depth = max(depth, diffuse)
                sizes["PLASTIC_DIFFUSE_LEVELS"] = diffuse
            sizes.update(PRODUCT_LEVELS=depth, LOBE_SHAPES=lobe_shapes, PRODUCT_TREES=int(trees.n_trees))
            if getattr(strategy, "candidates", 0):   # resampling from product candidates
                sizes.update(zip(("RIS_PRODUCT", "RIS_BSDF"), strategy.ris_split))
                sizes["RIS_CONTROL_VARIATE"] = int(bool(strategy.control_variate))
                sizes["RIS_SLOTS"] = self.slots = int(strategy.slots)
        self._tables = (self.kind, self.param, self.albedo, self.table, self.kappa, self.levels_per_material,
                        self.texels, *self.env_size, self.rot, self.tree)
        self._geometry = self._smooth = None
        self.textured = bool(getattr(scene, "textured", False)) and tracer is not None
        if tracer is not None:   # face normals and materials for shade_rays (a dummy row without faces)
            rows = np.zeros((max(len(tracer.face_normals), 1), 4), np.float32)   # normal, offset floor
            rows[:len(tracer.face_normals), :3] = tracer.face_normals
            rows[:len(tracer.face_normals), 3] = tracer.face_offset_floor
            materials = scene.face_material if len(scene.face_material) else np.zeros(1, np.int32)
            self._geometry = (cl.to_device(rows), cl.to_device(np.asarray(materials, np.int32)))
            corners = tracer.corner_normals if len(tracer.corner_normals) else np.zeros((1, 3), np.int32)
            self._smooth = (cl.to_device(np.ascontiguousarray(corners, np.int32)),
                            cl.to_device(np.ascontiguousarray(tracer.shading_normals, np.float32)),
                            np.int32(tracer.smooth))
        # base-colour textures (kernels/texture.h): the faces' texture coordinates, each material's
        # texture and the scene's texels in one buffer, uploaded once; dummies without textures
        if self.textured:
            texels, table = scene.texture_atlas()
            self._textures = (cl.to_device(textures.face_uv(scene.faces, scene.vertex_uv)),
                              cl.to_device(scene.material_texture), cl.to_device(texels), cl.to_device(table))
            sizes["TEXTURES"] = 1
        else:
            dummy = cl.to_device(np.zeros(8, np.float32))
            self._textures = (dummy, cl.to_device(np.full(max(len(scene.materials), 1), -1, np.int32)), dummy,
                              cl.to_device(np.zeros(4, np.int32)))
        if getattr(strategy, "heuristic", "power") == "balance":
            sizes["MIS_BALANCE"] = 1
        sizes["OFFSET_RELATIVE"] = repr(float(np.float32(raytrace.OFFSET_RELATIVE)))   # shadow-ray offsets
        sizes["SMOOTH_MIN_LENGTH2"] = repr(float(np.float32(raytrace.SMOOTH_MIN_LENGTH2))) + "f"
        if env.background == "bilinear":   # what camera rays that miss see (kernels/sphere.h env_bilinear)
            sizes["BACKGROUND_BILINEAR"] = 1
        self.program = cl.program("shade.cl", STRATEGY=strategies.KERNEL_ID[strategy.name], BSDF_KINDS=kinds,
                                  **sizes)
        self.warm_up()

    def __call__(self, n, wo, material, u, g=None, with_offset=False, tint=None, **_):
        """Shading points given directly (the ``shade`` kernel; tests): world shading normals n,
        geometric normals g (default n; both facing the viewer) and view directions wo (N, 3),
        material ids (N,), uniforms u (N, 4), ``tint`` (N, 3) multiplying each point's albedo (a
        texture's value there; None: 1) -> wi, value (N, S, 3) (S =
        ``slots``: 2, or 4 for the wavelet strategy's ``slots=4``), and
        with ``with_offset`` the estimates' part without a shadow ray, offset (N, 3) (the
        point's estimate is offset + the values of its visible slots)."""
        count = len(n)
        S = self.slots
        if count == 0:
            empty = np.zeros((0, S, 3), np.float32)
            return (empty, empty, np.zeros((0, 3), np.float32)) if with_offset else (empty, empty)
        q = cl.thread_queue()
        wi_buf, val_buf = cl.scratch("wi", count * 12 * S), cl.scratch("value", count * 12 * S)
        off_buf = cl.scratch("offset", count * 12)
        cl.kernel(self.program, "shade")(
            q, (cl.items(count, cl.LANES),), (cl.WORK_GROUP,), cl.upload("normal", np.asarray(n, np.float32), q),
            cl.upload("geometric", np.asarray(n if g is None else g, np.float32), q),
            cl.upload("wo", np.asarray(wo, np.float32), q),
            cl.upload("material", np.asarray(material, np.int32), q),
            cl.upload("tint", np.asarray(tint if tint is not None else np.ones((1, 3)), np.float32), q),
            np.int32(tint is not None), cl.upload("u", np.asarray(u, np.float32), q),
            np.uint32(count), *self._tables, wi_buf, val_buf, off_buf)
        # planes (slot, component, point) -> (point, slot, component) views
        wi = cl.read(wi_buf, (S, 3, count), np.float32, q).transpose(2, 0, 1)
        value = cl.read(val_buf, (S, 3, count), np.float32, q).transpose(2, 0, 1)
        if with_offset:
            return wi, value, cl.read(off_buf, (3, count), np.float32, q).T
        return wi, value

    def shade_rays(self, eye, d, prim, t, u, bary=None) -> ShadedRays:
        """Camera rays from ``eye`` along d (N, 3) that hit triangle prim (N,) (-1: a miss) at
        distance t (N,), with uniforms u: an (N, 4) array, or an :class:`rng.Stream` whose
        SHADING numbers the kernel draws itself (stratified as the stream says); ``bary`` (N, 2):
        embree's barycentric (u, v) of the hits (RayTracer.intersect_uv), needed where the scene
        has textures (None: every face shaded flat). One
        ``shade_rays`` launch into the thread's reusable buffers (the global size padded to the
        fixed work-group size: PoCL compiles once per work-group size, done in warm_up)."""
        if self._geometry is None:
            raise ValueError("KernelShader.shade_rays needs the ray tracer's geometry (tracer=...)")
        if self.textured and bary is None:
            raise ValueError("KernelShader.shade_rays: a textured scene needs the hits' barycentric coordinates (bary)")
        count = len(d)
        q = cl.thread_queue()
        S = self.slots
        bufs = [cl.scratch(name, size * count) for name, size in
                (("origin", 12), ("wi", 12 * S), ("value", 12 * S), ("direct", 12))]
        if count:
            if isinstance(u, rng.Stream):
                if u.k and count >= camera.MAX_PASS_RAYS:
                    raise ValueError(f"KernelShader.shade_rays: a stratified batch holds at most "
                                     f"{camera.MAX_PASS_RAYS - 1} rays, got {count}")
                draw = (np.int32(1), np.uint32(u.tile), np.uint32(u.first), *(np.uint32(x) for x in rng.key(u.seed)),
                        np.uint32(u.k))
                u_buf = self.tree   # not read
            else:
                draw = (np.int32(0), *(np.uint32(0),) * 5)
                u_buf = cl.upload("u", np.asarray(u, np.float32), q)
            smooth = self._smooth[2] if bary is not None else np.int32(0)
            bary_buf = (cl.upload("bary", np.asarray(bary, np.float32), q) if bary is not None and (smooth or self.textured)
                        else self.tree)   # (not read when flat and untextured)
            cl.kernel(self.program, "shade_rays")(
                q, (cl.items(count, cl.LANES),), (cl.WORK_GROUP,), cl.upload("dirs", np.asarray(d, np.float32), q),
                cl.upload("prim", np.asarray(prim, np.int32), q), cl.upload("tfar", np.asarray(t, np.float32), q),
                *np.asarray(eye, np.float32), raytrace.RayTracer.eye_offset_floor(eye), *self._geometry, bary_buf,
                *self._smooth[:2], smooth, *self._textures, u_buf, *draw, np.uint32(count), *self._tables, *bufs)
        origin, wi, value, direct = (cl.read(b, shape, np.float32, q) for b, shape in
                                     zip(bufs, ((count, 3), (count, S, 3), (S, 3, count), (3, count))))
        return ShadedRays(direct, origin, wi, value)

    def warm_up(self):
        """A tiny and a large launch, so that PoCL's per-launch compilation lands in setup time, not
        render time: PoCL builds a kernel once per work-group size and again for large grids (its
        "smallgrid" specialisation covers small ones; 4 096 work-items still counted as small,
        65 536 did not), and renders launch both. Once per process, program and kernel: the
        renderer's ``shade_rays`` when the shader has geometry, else ``shade``."""
        key = (self.program, self._geometry is not None)
        if key in _WARMED:
            return
        for count in (1, 1 << 16):
            up = np.tile(np.float32([0.0, 0.0, 1.0]), (count, 1))
            u = np.full((count, 4), 0.5, np.float32)
            if self._geometry is None:
                self(up, up, np.zeros(count, np.int32), u)
            else:
                self.shade_rays(np.zeros(3), up, np.full(count, -1, np.int32), np.ones(count, np.float32), u,
                                np.zeros((count, 2), np.float32))
        _WARMED.add(key)


def shade_rays_reference(shade, scene, tracer, eye, d, prim, t, u, bary=None) -> ShadedRays:
    """numpy twin of ``shade_rays`` in kernels/shade.cl, around a shader of points
    ``shade(n, wo, material, u, p=..., g=..., with_offset=True, tint=...) -> wi, value (M, S, 3),
    offset (M, 3)``, with u an (N, 4) array or an :class:`rng.Stream` (its SHADING numbers, as the
    kernel draws them): misses see the environment (:meth:`Environment.eval_background`); hits take
    their shading normal (``tracer.hit`` at embree's barycentric ``bary`` (N, 2); without them the
    face normal) and their face normal, both flipped towards the viewer, their face's material (in a
    textured scene its texture at the hit: Scene.albedo_at), the offset as their direct part, and
    shadow rays from the hit point moved ``tracer.shadow_offsets`` along the face normal."""
    d = np.asarray(d, np.float32)
    prim = np.asarray(prim)
    count = len(d)
    if isinstance(u, rng.Stream):
        u = u.uniforms(rng.SHADING, count)
    miss = prim < 0
    hit = np.flatnonzero(~miss)
    direct = np.zeros((3, count))
    direct[:, miss] = scene.environment.eval_background(d[miss].astype(np.float64)).T
    face = prim[hit]
    origin = np.zeros((count, 3), np.float32)
    if bary is not None and tracer.smooth:
        b = np.asarray(bary)[hit]
        n, g, p, origin[hit] = tracer.hit(eye, d[hit], np.asarray(t, np.float32)[hit], face, b[:, 0], b[:, 1])
    else:
        n, p, origin[hit] = tracer.surface(eye, d[hit], np.asarray(t, np.float32)[hit], face)
        g = n
    if len(hit):
        tint = None
        if getattr(scene, "textured", False):
            if bary is None:
                raise ValueError("shade_rays_reference: a textured scene needs the hits' barycentric coordinates")
            b = np.asarray(bary, np.float32)[hit]
            tex_uv = textures.hit_uv(textures.face_uv(scene.faces, scene.vertex_uv), face, b[:, 0], b[:, 1])
            texels, table = scene.texture_atlas()
            tint = textures.lookup(texels, table, scene.material_texture[scene.face_material[face]], tex_uv)
        wi_h, val_h, off_h = shade(n, -d[hit], scene.face_material[face], np.asarray(u)[hit], p=p, g=g,
                                   with_offset=True, tint=tint)
        direct[:, hit] = np.asarray(off_h).T
    else:   # (no call: some shaders do not take zero points)
        wi_h = val_h = np.zeros((0, 2, 3))
    wi = np.zeros((count,) + wi_h.shape[1:])
    value = np.zeros((val_h.shape[1], 3, count))
    wi[hit] = wi_h
    value[:, :, hit] = np.asarray(val_h).transpose(1, 2, 0)
    return ShadedRays(direct, origin, wi, value)


class NumpyShader:
    """The same call as :class:`KernelShader`, computed by the numpy reference.

    Strategies without a kernel whose estimator is not one f L cos / pdf per direction
    (``sir``) define ``shade(env, sp, u) -> wi (N, S, 3), value (N, S, 3)`` with their own
    number of slots S; those are called instead of :func:`strategies.shade_reference`.
    """

    def __init__(self, scene, strategy: strategies.Strategy, tracer=None):
        self.scene, self.strategy, self.tracer = scene, strategy, tracer
        self.table = material_table(scene)

    def shade_rays(self, eye, d, prim, t, u, bary=None) -> ShadedRays:
        """Camera rays as in :meth:`KernelShader.shade_rays`, by :func:`shade_rays_reference`."""
        return shade_rays_reference(self, self.scene, self.tracer, eye, d, prim, t, u, bary)

    def __call__(self, n, wo, material, u, p=None, g=None, with_offset=False, tint=None):
        """As :meth:`KernelShader.__call__` (``p``: the hit points, for shaders that need them)."""
        sc = self.scene
        n = np.asarray(n, np.float64)
        s, t = warp.frame(n)
        albedo = sc.material_albedo[material]
        if tint is not None:
            albedo = albedo * np.asarray(tint, np.float32)
        g_local = None if g is None else warp.to_local(np.asarray(g, np.float64), s, t, n)
        sp = strategies.ShadingPoints(p, n, s, t, warp.to_local(np.asarray(wo, np.float64), s, t, n),
                                      sc.material_kind[material], sc.material_param[material],
                                      albedo, np.asarray(material), self.table[material], g_local)
        own = getattr(self.strategy, "shade", None)
        if own is not None:
            wi, value = own(sc.environment, sp, np.asarray(u, np.float64))
            return (wi, value, np.zeros((len(n), 3))) if with_offset else (wi, value)
        return strategies.shade_reference(self.strategy, sc.environment, sp, np.asarray(u, np.float64),
                                          with_offset=with_offset)
