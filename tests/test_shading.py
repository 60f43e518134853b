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
from scenes_util import random_normals_views
from walks import product_kernel_samples


def _scene(pixels, rotate_y=0.0, phong_exponent=80.0):
    mats = [Material("l", bsdfs.LAMBERT, np.array([0.7, 0.5, 0.3], np.float32), 0.0),
            Material("p", bsdfs.PHONG, np.array([0.9, 0.9, 0.9], np.float32), phong_exponent),
            Material("g", bsdfs.GGX, np.array([1.0, 0.8, 0.4], np.float32), 0.1),
            Material("g2", bsdfs.GGX, np.array([1.0, 0.8, 0.4], np.float32), 0.6)]
    cam = Camera(np.zeros(3), np.array([0, 0, -1.0]), np.array([0, 1.0, 0]), 40.0)
    return Scene("t", 8, 8, 1, "mis", 0, cam, Environment(pixels, 1.0, rotate_y), np.zeros((0, 3), np.float32),
                 np.zeros((0, 3), np.int32), np.zeros(0, np.int32), mats)


@pytest.mark.slow
@pytest.mark.parametrize("strategy", ["uniform", "cosine", "bsdf", "light", "mis", "mis_comp", "wavelet",
                                      "wavelet:levels=6"])
@pytest.mark.parametrize("rotate_y", [0.0, 70.0])
def test_shade_kernel_matches_numpy(strategy, rotate_y):
    """wavelet:levels=6: product depth 6 for every material, so that lambert (default depth 3, all
    look-ahead levels) also reads its own light tree's child masses in product_pdf."""
    rng = np.random.default_rng(11)
    scene = _scene(procedural_sky(width=128, height=64, sun_radiance=500.0) + rng.random((64, 128, 3)) * 0.2,
                   rotate_y)
    name, _, levels = strategy.partition(":levels=")
    _compare_shaders(scene, strategies.make(name, **({"levels": int(levels)} if levels else {})), rng)


@pytest.mark.parametrize("strategy", ["uniform", "bsdf", "mis"])
def test_phong_exponent_zero_kernel_matches_numpy(strategy):
    """Phong with n = 0 is uniform over the hemisphere about the mirror direction and 0 outside
    it in both (numpy's 0 ** 0 = 1 once gave it the whole sphere: a 1.5% brighter image)."""
    rng = np.random.default_rng(12)
    scene = _scene(procedural_sky(width=128, height=64, sun_radiance=500.0) + rng.random((64, 128, 3)) * 0.2,
                   phong_exponent=0.0)
    _compare_shaders(scene, strategies.make(strategy), rng)


@pytest.mark.slow
def test_shade_kernel_matches_numpy_four_slots():
    """The resampling estimator with four slots (two more directions per sample, at u.z + 1/4 and
    + 3/4): kernel and numpy twin, as above; the shapes carry four slots."""
    rng = np.random.default_rng(13)
    scene = _scene(procedural_sky(width=128, height=64, sun_radiance=500.0) + rng.random((64, 128, 3)) * 0.2, 30.0)
    strat = strategies.make("wavelet", slots=4)
    assert _compare_shaders(scene, strat, rng)[0].shape[1] == 4


def test_slot_shifts_nest():
    """Slot k picks at u.z + k' / S, k' the bit reversal of k: two slots at 0 and 1/2, four at
    0, 1/2, 1/4, 3/4 (the kernel's a, b, c, d), and the first S' of S slots are the S' slots of a
    smaller budget; every shift is a distinct multiple of 1/S."""
    assert [strategies.slot_shift(k, 2) for k in range(2)] == [0.0, 0.5]
    assert [strategies.slot_shift(k, 4) for k in range(4)] == [0.0, 0.5, 0.25, 0.75]
    eight = [strategies.slot_shift(k, 8) for k in range(8)]
    assert eight[:4] == [0.0, 0.5, 0.25, 0.75]
    assert sorted(eight) == [k / 8 for k in range(8)]


def _compare_shaders(scene, strat, rng):
    """Shading normals n and, for half of the points, a geometric normal g that leans away from n
    (facing the viewer, as a hit's): directions below g carry no light in both."""
    strat.prepare(scene.environment, scene.materials)
    n_pts = 20000
    n, wo = random_normals_views(rng, n_pts)
    g = n + 0.5 * rng.normal(size=n.shape) * (np.arange(n_pts) % 2)[:, None]
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    g *= np.where(np.einsum("ij,ij->i", g, wo) < 0, -1.0, 1.0)[:, None]
    mat = rng.integers(0, 4, n_pts).astype(np.int32)
    u = rng.random((n_pts, 4), dtype=np.float32)
    wi_k, val_k = KernelShader(scene, strat)(n, wo, mat, u, g=g)
    wi_r, val_r = NumpyShader(scene, strat)(n, wo, mat, u, g=g)
    live = np.abs(val_r).max(axis=2) > 0
    dir_ok = np.abs(wi_k - wi_r).max(axis=2) < 2e-4
    val_ok = np.isclose(val_k, val_r, rtol=2e-3, atol=1e-6).all(axis=2)
    assert np.isfinite(val_k).all()
    assert (dir_ok | ~live).mean() > 0.999
    assert val_ok.mean() > 0.999, f"{(~val_ok).sum()} of {val_ok.size} values differ"
    assert live.any()
    return wi_k, val_k


def _plastic_scene(pixels, rotate_y=30.0):
    """Two plastic materials between a lambert and a ggx one (a program with every kind the
    plastic rows sit between)."""
    mats = [Material("l", bsdfs.LAMBERT, np.array([0.7, 0.5, 0.3], np.float32), 0.0),
            Material("pl", bsdfs.PLASTIC, np.array([0.8, 0.2, 0.1], np.float32), 0.05, 1.5),
            Material("g", bsdfs.GGX, np.array([1.0, 0.8, 0.4], np.float32), 0.1),
            Material("pl2", bsdfs.PLASTIC, np.array([0.1, 0.5, 0.9], np.float32), 0.4, 1.7)]
    cam = Camera(np.zeros(3), np.array([0, 0, -1.0]), np.array([0, 1.0, 0]), 40.0)
    return Scene("t", 8, 8, 1, "mis", 0, cam, Environment(pixels, 1.0, rotate_y), np.zeros((0, 3), np.float32),
                 np.zeros((0, 3), np.int32), np.zeros(0, np.int32), mats)


@pytest.mark.slow
@pytest.mark.parametrize("strategy, options", [
    ("uniform", {}), ("cosine", {}), ("bsdf", {}), ("light", {}), ("mis", {}), ("mis_comp", {}),
    ("wavelet", {"candidates": 0}), ("wavelet", {"candidates": 8}), ("wavelet", {"candidates": 8, "slots": 4}),
    ("wavelet", {"candidates": 6, "control_variate": False})],
    ids=["uniform", "cosine", "bsdf", "light", "mis", "mis_comp", "wavelet-pair", "wavelet-ris",
         "wavelet-ris-4", "wavelet-ris-nocv"])
def test_shade_kernel_matches_numpy_plastic(strategy, options):
    """Plastic (each slot's colour 1 - k + k albedo, k the diffuse share of f cos; wavelet's
    mixture of the specular and diffuse lobes' walks): kernel and numpy twin as above, the
    control variate's offset included."""
    rng = np.random.default_rng(21)
    scene = _plastic_scene(procedural_sky(width=128, height=64, sun_radiance=500.0) + rng.random((64, 128, 3)) * 0.2)
    strat = strategies.make(strategy, **options)
    strat.prepare(scene.environment, scene.materials)
    n_pts = 20000
    n, wo = random_normals_views(rng, n_pts)
    mat = rng.integers(0, 4, n_pts).astype(np.int32)
    u = rng.random((n_pts, 4), dtype=np.float32)
    wi_k, val_k, off_k = KernelShader(scene, strat)(n, wo, mat, u, with_offset=True)
    wi_r, val_r, off_r = NumpyShader(scene, strat)(n, wo, mat, u, with_offset=True)
    live = np.abs(val_r).max(axis=2) > 0
    dir_ok = np.abs(wi_k - wi_r).max(axis=2) < 2e-4
    val_ok = np.isclose(val_k, val_r, rtol=2e-3, atol=1e-6).all(axis=2)
    off_ok = np.isclose(off_k, off_r, rtol=2e-3, atol=1e-5).all(axis=1)
    plastic = np.isin(mat, [1, 3])
    assert np.isfinite(val_k).all() and np.isfinite(off_k).all()
    assert (dir_ok | ~live).mean() > 0.999
    assert val_ok.mean() > 0.999, f"{(~val_ok).sum()} of {val_ok.size} values differ"
    assert val_ok[plastic].mean() > 0.999
    assert off_ok.mean() > 0.999
    assert live[plastic].any()


@pytest.mark.parametrize("sampler", ["independent", "stratified"])
def test_render_kernel_equals_numpy_backend(sampler):
    """The whole renderer with the kernel and with the numpy twin, same seeds and sampler."""
    scene = wavlight.load_scene("scenes/default.toml")
    for strategy in ("bsdf", "mis"):
        a = wavlight.render_full(scene, strategy=strategy, spp=4, width=32, height=24, sampler=sampler)
        b = wavlight.render_full(scene, strategy=strategy, spp=4, width=32, height=24, backend="numpy",
                                 sampler=sampler)
        close = np.isclose(a.image, b.image, rtol=1e-3, atol=1e-4)
        assert close.mean() > 0.998


@pytest.mark.slow
@pytest.mark.parametrize("n_trees, shapes", [(1, 15), (2, 15), (1, 1), (2, 1)],
                         ids=["one_tree", "two_trees", "one_tree-lambert_only", "two_trees-lambert_only"])
def test_product_sample_points_kernel_matches_numpy(n_trees, shapes):
    """kernels/product.cl (the renderer's product guide samples) against wavlight.strategies.product.sample_reference,
    for every lobe shape and product depth, in one program built for all of them; with two light
    trees (plain and compensated, as WaveletStrategy holds them for lambert and glossy materials in
    one scene) each material walks its own. shapes: the LOBE_SHAPES the program is built for (15
    every shape; 1 lambert alone, whose lobe_weight returns the softened cosine directly)."""
    from wavlight.strategies import product
    from wavlight.haar.tree import HaarTree

    rng = np.random.default_rng(5)
    env = Environment(procedural_sky(width=128, height=64, sun_radiance=300.0) + rng.random((64, 128, 3)) * 0.3,
                      1.0, 35.0)
    n_levels = env.square_levels()
    tree = HaarTree(np.stack([env.luminance_square(n_levels, compensated=c) for c in (False, True)][:n_trees]))
    count = 4093  # not a multiple of the work-group size: the masked tail is exercised too
    nrm, wo = random_normals_views(rng, count)
    # materials: every shape (lambert, phong, ggx, ggx with the half-vector model) at every depth
    kinds = [k for k in range(4) if shapes >> k & 1]
    mat_shape = np.repeat(np.array(kinds), n_levels + 1)
    mat_depth = np.tile(np.arange(n_levels + 1), len(kinds))
    mat_kappa = np.where(mat_shape == bsdfs.LAMBERT, 0.0, np.where(mat_shape == bsdfs.PHONG, 50.0, 12.5))
    mat_tree = np.arange(len(mat_shape)) % n_trees
    material = rng.integers(0, len(mat_shape), count)
    shape, levels, kappa = mat_shape[material], mat_depth[material], mat_kappa[material]
    mirror = 2 * np.einsum("ij,ij->i", wo, nrm)[:, None] * nrm - wo
    axis = np.where((shape == bsdfs.LAMBERT)[:, None], nrm, mirror)
    u = rng.random((count, 4), dtype=np.float32)   # the renderer's layout: u.xy draws the guide sample
    uv_k, pdf_k = product_kernel_samples(tree, env, n_levels, nrm, wo, material, mat_kappa, mat_depth, mat_shape,
                                         mat_tree, u, shapes, n_trees)
    u = u[:, :2]
    uv_r, pdf_r = product.sample_reference(tree.nodes(), n_levels, env, axis, nrm, kappa, levels, shape,
                                           u.astype(np.float64), mat_tree[material])
    # float32 kernel vs float64 reference: the same leaf for all but rounding ties at sibling
    # boundaries of the rescaled u; pdfs agree to float32 accuracy over <= 2 n products, except
    # where 1 - d.axis cancels in float32 for nodes next to the lobe axis (a few in 10^4)
    same_leaf = np.all(np.floor(uv_k * (1 << n_levels)) == np.floor(uv_r * (1 << n_levels)), axis=1)
    assert same_leaf.mean() > 0.995
    close = np.isclose(pdf_k[same_leaf], pdf_r[same_leaf], rtol=1e-3)
    assert close.mean() > 0.999
    np.testing.assert_allclose(pdf_k[same_leaf], pdf_r[same_leaf], rtol=2e-2)


@pytest.mark.slow
def test_breadth_first_walks_match_depth_first():
    """The stand-alone sample kernels wait at a work-group barrier before each step into a
    level of >= 256^2 nodes (kernels/warp.h BARRIER_LEVEL): the light walk (warp.cl) and the
    product walk (product.cl) through a 1024^2 tree give the same points and pdfs bit for bit
    with those barriers, with a barrier at every level (the product walk's below its product
    levels, product.h) and without any (the build the numpy
    comparisons above check), for a count that leaves whole work-items past its end (3001
    points: 376 work-items of 384, in 12 groups of cl.WALK_WORK_GROUP = 32 as HaarTree.sample
    launches them, the build without barriers in 6 of 64 as the renderer; an early return
    there breaks the barriers)."""
    from wavlight import cl
    from wavlight.haar.tree import HaarTree

    rng = np.random.default_rng(8)
    env = Environment(procedural_sky(width=256, height=128, sun_radiance=300.0) + rng.random((128, 256, 3)), 1.0, 20.0)
    n_levels = 10
    tree = HaarTree(env.luminance_square(n_levels))
    count = 3001
    nrm, wo = random_normals_views(rng, count)
    n4, w4 = np.zeros((count, 4), np.float32), np.zeros((count, 4), np.float32)
    n4[:, :3], w4[:, :3] = nrm, wo
    mat_shape = np.array([0, 1, 2, 3])
    mat_depth = np.array([3, 7, 7, 5])
    mat_kappa = np.array([0.0, 200.0, 200.0, 12.5], np.float32)
    material = rng.integers(0, 4, count).astype(np.int32)
    u = rng.random((count, 2), dtype=np.float32)
    q = cl.thread_queue()
    items = cl.items(count, cl.LANES)
    product_args = (tree.buffer, cl.to_device(env.map_from_world.astype(np.float32).ravel()), np.uint32(count),
                    cl.to_device(n4), cl.to_device(w4), cl.to_device(material), cl.to_device(mat_kappa),
                    cl.to_device((mat_depth + 256 * mat_shape).astype(np.int32)), cl.to_device(u), np.uint32(2))
    light_args = (tree.buffer, np.uint64(tree.stride), np.uint32(count), np.uint32(count), cl.to_device(u),
                  np.uint32(2))
    results = {}
    for build in ({}, {"BARRIER_LEVEL": 1}, {"WALK_BARRIERS": 0}):
        out = []
        for name, kernel, defines, args in (
                ("product.cl", "product_sample_points", dict(PRODUCT_LEVELS=7, LOBE_SHAPES=15), product_args),
                ("warp.cl", "warp_sample", dict(BATCHED=0), light_args)):
            uv_buf, pdf_buf = cl.empty(8 * count), cl.empty(4 * count)
            prog = cl.program(name, N_LEVELS=n_levels, **defines, **build)
            group = cl.WORK_GROUP if build.get("WALK_BARRIERS") == 0 else cl.WALK_WORK_GROUP
            cl.kernel(prog, kernel)(q, (items,), (group,), *args, uv_buf, pdf_buf)
            out += [cl.read(uv_buf, (2, count), np.float32, q), cl.read(pdf_buf, (count,), np.float32, q)]
        results[str(build)] = out
    base = results["{'WALK_BARRIERS': 0}"]
    assert all(np.all(p > 0) for p in base[1::2])   # every walk found mass
    for build, out in results.items():
        for got, want in zip(out, base):
            np.testing.assert_array_equal(got, want, err_msg=build)


@pytest.mark.slow
@pytest.mark.parametrize("strategy", ["uniform", "cosine", "bsdf", "light", "mis", "mis_comp", "wavelet",
                                      "wavelet:no-control-variate", "wavelet:four-slots"])
@pytest.mark.parametrize("drawn", [None, 0, 13], ids=["u-given", "u-drawn", "u-stratified"])
def test_shade_rays_kernel_matches_numpy(strategy, drawn):
    """kernels/shade.cl shade_rays (the renderer's entry: camera rays from the tracer, hits and
    misses) against shading.shade_rays_reference, on the default scene with its map rotated
    and random texels added. Misses: the same texel as Environment.eval except where float32
    and float64 round a direction to different sides of a texel edge (a few in 10^5); hits:
    shadow origins, directions and estimates as in test_shade_kernel_matches_numpy. The ray
    count is not a multiple of 8, so the last work-item's partial lanes are exercised. The
    uniforms are given, or drawn by the kernel from Philox: independent (numpy twin
    rng.uniforms) or stratified over pixels of 13 samples (rng.Stream with k = 13, whose
    count is not a multiple of 13 either). Hits' direct part is 0 but for the wavelet
    control variate's offset (compared through U = offset + both values)."""
    from wavlight import camera, rng as philox
    from wavlight.raytrace import RayTracer

    scene = wavlight.load_scene("scenes/default.toml")
    rng = np.random.default_rng(12)
    env = scene.environment
    scene.environment = Environment(env.pixels + rng.random(env.pixels.shape).astype(np.float32) * 0.2, 1.0, 50.0)
    tracer = RayTracer(scene.vertices, scene.faces, normals=scene.normals, normal_faces=scene.normal_faces)
    assert tracer.smooth
    name, _, variant = strategy.partition(":")
    strat = strategies.make(name, **{"no-control-variate": {"control_variate": False},
                                     "four-slots": {"slots": 4}}.get(variant, {}))
    strat.prepare(scene.environment, scene.materials)
    count = 40_003
    w, h = 64, 48
    o, d = camera.camera_rays(scene, rng.integers(0, w, count), rng.integers(0, h, count), rng.random((count, 2)),
                                  w, h)
    prim, t, bu, bv = tracer.intersect_uv(o, d)
    assert 0.1 < (prim >= 0).mean() < 0.9                       # both hits and misses
    u = rng.random((count, 4), dtype=np.float32) if drawn is None else philox.Stream(5, 17, 3000, drawn)
    got = KernelShader(scene, strat, tracer).shade_rays(scene.camera.eye, d, prim, t, u, np.stack([bu, bv], 1))
    ref = NumpyShader(scene, strat, tracer).shade_rays(scene.camera.eye, d, prim, t, u, np.stack([bu, bv], 1))
    miss, hit = prim < 0, prim >= 0
    assert got.direct.shape == ref.direct.shape == (3, count)
    assert np.all(got.value[:, :, miss] == 0)
    if getattr(strat, "candidates", 0) and strat.control_variate:
        # hits' direct part: the control variate's offset albedo U - value_a - value_b, so
        # offset + both values = albedo U, which does not depend on the picks
        u_got = got.direct[:, hit] + got.value[:, :, hit].sum(0)
        u_ref = ref.direct[:, hit] + ref.value[:, :, hit].sum(0)
        assert np.isclose(u_got, u_ref, rtol=2e-3, atol=1e-5).all(axis=0).mean() > 0.999
    else:
        assert np.all(got.direct[:, hit] == 0)
    assert np.all(got.direct[:, miss] == ref.direct[:, miss], axis=0).mean() > 0.9995
    np.testing.assert_allclose(got.origin[hit], ref.origin[hit], atol=1e-5 * tracer.scale)
    live = np.abs(ref.value[:, :, hit]).max(axis=1) > 0            # (slot, hit)
    dir_ok = np.abs(got.wi[hit] - ref.wi[hit]).max(axis=2).T < 2e-4
    val_ok = np.isclose(got.value[:, :, hit], ref.value[:, :, hit], rtol=2e-3, atol=1e-6).all(axis=1)
    assert np.isfinite(got.value).all()
    assert (dir_ok | ~live).mean() > 0.999
    assert val_ok.mean() > 0.999, f"{(~val_ok).sum()} of {val_ok.size} values differ"
    assert live.any()
