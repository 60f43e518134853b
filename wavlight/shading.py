"""Shading on the OpenCL device: kernels/shade.cl.

:class:`KernelShader` uploads the environment (texels, rotation), the light tree
and the material table once, then shades batches of points with one launch of the
``shade`` kernel (eight points per work-item): for each point one direction per
strategy sample (two for MIS; the light or product sample walks its tree in the
kernel) and its unoccluded estimate. Its numpy
twin is :func:`wavlight.strategies.shade_reference`; :class:`NumpyShader` wraps
that twin behind the same call, for tests and for devices without OpenCL.
"""
from __future__ import annotations

import numpy as np

from . import cl, product, strategies, warp

_WARMED = set()  # shade programs already launched in this process


class KernelShader:
    """shade(n, wo, material, u) -> wi (N, 2, 3), value (N, 2, 3), float32."""

    def __init__(self, scene, strategy: strategies.Strategy):
        env = scene.environment
        self.strategy = strategy
        texels = np.zeros((env.height * env.width, 4), np.float32)
        texels[:, :3] = env.pixels.reshape(-1, 3)
        self.env_size = (np.int32(env.width), np.int32(env.height))
        self.texels = cl.to_device(texels)
        self.rot = cl.to_device(env.map_from_world.astype(np.float32).ravel())
        light = getattr(strategy, "light", strategy if isinstance(strategy, strategies.LightStrategy) else None)
        if light is not None:
            self.tree, self.levels = light.tree.buffer, np.int32(light.tree.n_levels)
        else:
            self.tree, self.levels = cl.to_device(np.zeros(1, np.float32)), np.int32(0)
        self.kind = cl.to_device(scene.material_kind.astype(np.int32))
        self.param = cl.to_device(scene.material_param.astype(np.float32))
        alb = np.zeros((len(scene.materials), 4), np.float32)
        alb[:, :3] = scene.material_albedo
        self.albedo = cl.to_device(alb)
        kappa = getattr(strategy, "kappa", np.zeros(len(scene.materials)))
        levels = np.asarray(getattr(strategy, "levels", np.zeros(len(scene.materials), np.int32)), np.int32)
        self.kappa = cl.to_device(np.asarray(kappa, np.float32))
        shapes = np.asarray(getattr(strategy, "shapes", np.zeros(len(scene.materials), np.int32)), np.int32)
        # depth + 256 lobe shape (kernels/product.h make_lobe decodes both)
        self.levels_per_material = cl.to_device(levels + 256 * shapes)
        depth = int(max(np.max(levels, initial=0), 0))
        self.angles = cl.to_device(product.node_angles(depth))
        kinds = int(np.bitwise_or.reduce(1 << np.asarray(scene.material_kind, np.int64), initial=0)) or 1
        sizes = {}   # the walks' compile-time sizes: light tree depth; product depth and lobe shapes
        if strategy.name in ("light", "mis", "wavelet"):
            sizes["N_LEVELS"] = int(self.levels)
        if strategy.name == "wavelet":
            sizes.update(PRODUCT_LEVELS=depth, LOBE_SHAPES=int(np.bitwise_or.reduce(1 << shapes, initial=0)))
        self.program = cl.program("shade.cl", STRATEGY=strategies.KERNEL_ID[strategy.name], BSDF_KINDS=kinds,
                                  **sizes)
        self.warm_up()

    def __call__(self, n, wo, material, u, **_):
        count = len(n)
        if count == 0:
            return np.zeros((0, 2, 3), np.float32), np.zeros((0, 2, 3), np.float32)
        # The global size is padded to a fixed work-group size: PoCL compiles a kernel per
        # work-group size on first launch, so this keeps it to one compile (done in warm_up).
        # The kernel takes eight points per work-item (kernels/simd.h). Its buffers are the
        # thread's scratch buffers, reused from batch to batch.
        q = cl.thread_queue()
        wi_buf, val_buf = cl.scratch("wi", count * 24), cl.scratch("value", count * 24)
        cl.kernel(self.program, "shade")(
            q, (cl.items(count, cl.LANES),), (cl.WORK_GROUP,), cl.upload("normal", np.asarray(n, np.float32), q),
            cl.upload("wo", np.asarray(wo, np.float32), q),
            cl.upload("material", np.asarray(material, np.int32), q), cl.upload("u", np.asarray(u, np.float32), q),
            np.uint32(count), self.kind, self.param, self.albedo, self.kappa, self.levels_per_material, self.angles,
            self.texels, *self.env_size, self.rot, self.tree, wi_buf, val_buf)
        # planes (slot, component, point) -> (point, slot, component) views
        wi = cl.read(wi_buf, (2, 3, count), np.float32, q).transpose(2, 0, 1)
        value = cl.read(val_buf, (2, 3, count), np.float32, q).transpose(2, 0, 1)
        return wi, value

    def environment(self, d):
        """Radiance (N, 3) float32 of the environment along world directions d (N, 3): camera
        rays that miss (kernels/shade.cl env_radiance; numpy twin Environment.eval)."""
        count = len(d)
        if count == 0:
            return np.zeros((0, 3), np.float32)
        q = cl.thread_queue()
        out = cl.scratch("env_rgb", 12 * count)
        cl.kernel(self.program, "env_radiance")(
            q, (cl.items(count, cl.LANES),), (cl.WORK_GROUP,), cl.upload("env_dirs", np.asarray(d, np.float32).T, q),
            np.uint32(count), self.texels, *self.env_size, self.rot, out)
        return cl.read(out, (3, count), np.float32, q).T

    def warm_up(self):
        """A tiny and a large launch, so that PoCL's per-launch compilation lands in setup time, not
        render time: PoCL builds a kernel once per work-group size and again for large grids (its
        "smallgrid" specialisation covers small ones; 4 096 work-items still counted as small,
        65 536 did not), and renders launch both. Once per process and set of programs."""
        key = self.program
        if key in _WARMED:
            return
        for count in (1, 1 << 16):
            self(np.tile([[0.0, 0.0, 1.0]], (count, 1)), np.tile([[0.0, 0.0, 1.0]], (count, 1)),
                 np.zeros(count, np.int32), np.full((count, 4), 0.5, np.float32))
            self.environment(np.tile([[0.0, 0.0, 1.0]], (count, 1)))
        _WARMED.add(key)


class NumpyShader:
    """The same call as :class:`KernelShader`, computed by the numpy reference.

    Strategies without a kernel whose estimator is not one f L cos / pdf per direction
    (``sir``) define ``shade(env, sp, u) -> wi (N, S, 3), value (N, S, 3)`` with their own
    number of slots S; those are called instead of :func:`strategies.shade_reference`.
    """

    def __init__(self, scene, strategy: strategies.Strategy):
        self.scene, self.strategy = scene, strategy

    def environment(self, d):
        """Radiance (N, 3) of the environment along world directions d (N, 3)."""
        return self.scene.environment.eval(np.asarray(d, np.float64))

    def __call__(self, n, wo, material, u, p=None):
        sc = self.scene
        n = np.asarray(n, np.float64)
        s, t = warp.frame(n)
        sp = strategies.ShadingPoints(p, n, s, t, warp.to_local(np.asarray(wo, np.float64), s, t, n),
                                      sc.material_kind[material], sc.material_param[material],
                                      sc.material_albedo[material], np.asarray(material))
        own = getattr(self.strategy, "shade", None)
        if own is not None:
            return own(sc.environment, sp, np.asarray(u, np.float64))
        return strategies.shade_reference(self.strategy, sc.environment, sp, np.asarray(u, np.float64))
