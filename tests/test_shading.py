"""The shade kernel against its numpy twin.

The kernel works in float32 and the reference in float64, from the same uniform
numbers: directions agree to ~1e-5, values to ~1e-4 relative, except where a
direction falls within float rounding of a texel or leaf edge (then the two may
look up neighbouring texels); we allow 0.1% of such samples.
"""
import numpy as np
import pytest

import wavlight
from wavlight import bsdfs, strategies
from wavlight.envmap import Environment, procedural_sky
from wavlight.scene import Camera, Material, Scene
from wavlight.shading import KernelShader, NumpyShader


def _scene(pixels, rotate_y=0.0):
    mats = [Material("l", bsdfs.LAMBERT, np.array([0.7, 0.5, 0.3], np.float32), 0.0),
            Material("p", bsdfs.PHONG, np.array([0.9, 0.9, 0.9], np.float32), 80.0),
            Material("g", bsdfs.GGX, np.array([1.0, 0.8, 0.4], np.float32), 0.1),
            Material("g2", bsdfs.GGX, np.array([1.0, 0.8, 0.4], np.float32), 0.6)]
    cam = Camera(np.zeros(3), np.array([0, 0, -1.0]), np.array([0, 1.0, 0]), 40.0)
    return Scene("t", 8, 8, 1, "mis", 0, cam, Environment(pixels, 1.0, rotate_y), np.zeros((0, 3), np.float32),
                 np.zeros((0, 3), np.int32), np.zeros(0, np.int32), mats)


@pytest.mark.parametrize("strategy", ["uniform", "cosine", "bsdf", "light", "mis", "wavelet"])
@pytest.mark.parametrize("rotate_y", [0.0, 70.0])
def test_shade_kernel_matches_numpy(strategy, rotate_y):
    rng = np.random.default_rng(11)
    scene = _scene(procedural_sky(width=128, height=64, sun_radiance=500.0) + rng.random((64, 128, 3)) * 0.2,
                   rotate_y)
    strat = strategies.make(strategy)
    strat.prepare(scene.environment, scene.materials)
    n_pts = 20000
    n = rng.normal(size=(n_pts, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    wo = rng.normal(size=(n_pts, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wo *= np.sign(np.einsum("ij,ij->i", wo, n))[:, None]
    mat = rng.integers(0, 4, n_pts).astype(np.int32)
    u = rng.random((n_pts, 4), dtype=np.float32)
    wi_k, val_k = KernelShader(scene, strat)(n, wo, mat, u)
    wi_r, val_r = NumpyShader(scene, strat)(n, wo, mat, u)
    live = np.abs(val_r).max(axis=2) > 0
    dir_ok = np.abs(wi_k - wi_r).max(axis=2) < 2e-4
    val_ok = np.isclose(val_k, val_r, rtol=2e-3, atol=1e-6).all(axis=2)
    assert np.isfinite(val_k).all()
    assert (dir_ok | ~live).mean() > 0.999
    assert val_ok.mean() > 0.999, f"{(~val_ok).sum()} of {val_ok.size} values differ"
    assert live.any()


def test_render_kernel_equals_numpy_backend():
    """The whole renderer with the kernel and with the numpy twin, same seeds."""
    scene = wavlight.load_scene("scenes/default.toml")
    for strategy in ("bsdf", "mis"):
        a = wavlight.render_full(scene, strategy=strategy, spp=4, width=32, height=24)
        b = wavlight.render_full(scene, strategy=strategy, spp=4, width=32, height=24, backend="numpy")
        close = np.isclose(a.image, b.image, rtol=1e-3, atol=1e-4)
        assert close.mean() > 0.998


def test_product_sample_points_kernel_matches_numpy():
    """kernels/product.cl (the benchmark's product warp) against wavlight.product.sample_reference."""
    from wavlight import cl, product
    from wavlight.distributions import HaarTree

    rng = np.random.default_rng(5)
    env = Environment(procedural_sky(width=128, height=64, sun_radiance=300.0) + rng.random((64, 128, 3)) * 0.3,
                      1.0, 35.0)
    n_levels = env.square_levels()
    tree = HaarTree(env.luminance_square(n_levels))
    count = 4093  # not a multiple of WALK_K: the masked tail is exercised too
    nrm = rng.normal(size=(count, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    axis = rng.normal(size=(count, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    shape = rng.integers(0, 4, count)  # lambert, phong, ggx, ggx with the half-vector model
    kappa = np.where(shape == bsdfs.LAMBERT, 0.0, np.where(shape == bsdfs.PHONG, 50.0, 12.5))  # ggx alpha 0.2
    levels = rng.integers(0, n_levels + 1, count)
    u = rng.random((count, 2), dtype=np.float32)
    depth = int(levels.max())
    q = cl.thread_queue()
    texels = np.zeros((env.height * env.width, 4), np.float32)
    texels[:, :3] = env.pixels.reshape(-1, 3)
    ak = np.concatenate([axis, kappa[:, None]], 1).astype(np.float32)
    nl = np.concatenate([nrm, (levels + 256 * shape)[:, None]], 1).astype(np.float32)
    uv_buf, pdf_buf = cl.empty(8 * count), cl.empty(4 * count)
    knl = cl.kernel(cl.program("product.cl"), "product_sample_points")
    knl(q, (-(-count // cl.WALK_K),), None, tree.buffer, np.int32(n_levels), cl.to_device(texels),
        np.int32(env.width), np.int32(env.height), cl.to_device(env.map_from_world.astype(np.float32).ravel()),
        np.uint32(count), cl.to_device(ak),
        cl.to_device(nl), cl.to_device(u), cl.to_device(product.node_directions(depth)), uv_buf, pdf_buf)
    uv_k = cl.read(uv_buf, (count, 2), np.float32, q)
    pdf_k = cl.read(pdf_buf, (count,), np.float32, q)
    uv_r, pdf_r = product.sample_reference(tree.nodes()[0], n_levels, env, axis, nrm, kappa, levels, shape,
                                           u.astype(np.float64))
    # float32 kernel vs float64 reference: the same leaf for all but rounding ties at sibling
    # boundaries of the rescaled u; pdfs agree to float32 accuracy over <= 2 n products, except
    # where 1 - d.axis cancels in float32 for nodes next to the lobe axis (a few in 10^4)
    same_leaf = np.all(np.floor(uv_k * (1 << n_levels)) == np.floor(uv_r * (1 << n_levels)), axis=1)
    assert same_leaf.mean() > 0.995
    close = np.isclose(pdf_k[same_leaf], pdf_r[same_leaf], rtol=1e-3)
    assert close.mean() > 0.999
    np.testing.assert_allclose(pdf_k[same_leaf], pdf_r[same_leaf], rtol=2e-2)
