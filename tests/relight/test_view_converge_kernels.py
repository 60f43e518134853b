"""The view bake's unbiased frame on the device (wavlight.relight.view_converge): the pixels'
product trees of kernels/relight_view_converge.cl against their numpy twin trees_reference, the
kernel frame against the numpy frame on the same random numbers (its shading is converge_shade,
whose twin tests/relight/test_converge_kernels.py compares), and the trees kept while the camera
stays. Unbiasedness against ``mis``: tests/relight/test_relight_view.py."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import wavlight
from scenes_util import write_lamp_sky
from wavlight import haar
from wavlight.envmap import Environment
from wavlight.relight import converge as cm
from wavlight.relight import mixture
from wavlight.relight import view_frames, view_walk
from wavlight.relight import view_converge as vc

EYE, TARGET = [2.0, 2.0, 3.0], [0.0, 0.5, 0.0]


def sphere_on_floor(ball=None):
    """A glossy sphere over a lambert floor under a sky with a small bright light, 36 x 20 pixels
    (not multiples of the kernels' work-groups)."""
    return {"render": {"width": 36, "height": 20},
            "camera": {"eye": [0.0, 1.5, 3.5], "target": [0.0, 0.5, 0.0], "fov_y": 40.0},
            "environment": {"file": "sky.exr", "rotate_y": 20.0},
            "objects": [{"shape": "sphere", "center": [0.0, 0.6, 0.0], "radius": 0.6, "subdivisions": 3,
                         "material": "ball"},
                        {"shape": "quad", "center": [0.0, 0.0, 0.0], "size": 6.0, "material": "floor"}],
            "materials": {"ball": ball or {"type": "ggx", "albedo": [0.9, 0.8, 0.6], "roughness": 0.3},
                          "floor": {"type": "lambert", "albedo": [0.6, 0.6, 0.6]}}}


@pytest.fixture(scope="module")
def bakes(tmp_path_factory, device):
    """The scene's view bakes (2^4 x 2^4 texels) at 8 and 16 bits."""
    folder = tmp_path_factory.mktemp("view_converge")
    write_lamp_sky(folder)   # a small bright light
    scene = wavlight.load_dict(sphere_on_floor(), base_dir=folder)
    out = {bits: wavlight.bake(scene, vary="view", levels=4, density=300, tolerance=1e-3, bits=bits)
           for bits in (8, 16)}
    return scene, out, folder


def texel_light(frames, levels):
    env = frames.environment
    return mixture.TexelLight(Environment(env.pixels, 1.0, 0.0, env.name), levels, env.rotate_y)


def converger(frames, inside):
    device = view_walk.ViewDevice(frames.transfer)
    return vc.ViewConverge(frames, inside, device, view_walk.FrameDevice(frames, device))


def camera_scene(frames, eye=EYE, target=TARGET):
    return dataclasses.replace(frames.scene, camera=frames.camera(eye, target, None))


def centre_rays(frames, scene, tile, width, height):
    P = tile.w * tile.h
    pix = np.arange(P)
    eye, d = vc.camera_rays(scene, tile.x0 + pix % tile.w, tile.y0 + pix // tile.w, np.full((P, 2), 0.5, np.float32),
                            width, height)
    prim, _, u, v = frames.tracer.intersect_uv(eye, d)
    return d, prim, u, v


@pytest.mark.parametrize("ball", [None, {"type": "phong", "albedo": [0.5, 0.6, 0.7], "exponent": 40.0},
                                  {"type": "lambert", "albedo": [0.5, 0.6, 0.7]},
                                  {"type": "plastic", "albedo": [0.6, 0.3, 0.1], "alpha": 0.2}])
@pytest.mark.parametrize("bits, levels", [(8, 4), (16, 4), (16, 2)])
def test_trees_kernel_equals_its_twin(bakes, bits, levels, ball, monkeypatch):
    """view_converge_trees against trees_reference, tile by tile (three tiles, the last one
    shorter), on pixels that see the ball, the floor, the sky and the ball from behind the
    baked camera: the pyramids (float32 against a float64 inverse transform), the relit values G;
    the trees are additive (parent = sum of children, as the warp needs) and a pixel without a
    cache point has a root of 0."""
    scene, by_bits, folder = bakes
    if ball is not None:   # the same transfer, another material on the ball (T1 has no BRDF in it)
        other = wavlight.load_dict(sphere_on_floor(ball), base_dir=folder)
        scene = dataclasses.replace(scene, materials=[other.materials[0], *scene.materials[1:]])
    frames = view_frames.ViewFrames(by_bits[bits], scene)
    inside = texel_light(frames, levels)
    conv = converger(frames, inside)
    monkeypatch.setattr(vc, "TILE_PIXELS", 36 * 8)
    width, height = 36, 20
    sc = camera_scene(frames)
    tiles = vc.tiles_of(width, height)
    assert [t.h for t in tiles] == [8, 8, 4]
    empty = product = 0
    for tile in tiles:
        trees, kept = conv.tile_trees(sc, tile, width, height)
        assert not kept
        nodes, relit = trees.read()
        d, prim, u, v = centre_rays(frames, sc, tile, width, height)
        want, want_relit = vc.trees_reference(frames, inside, d, prim, u, v)
        assert nodes.shape == want.shape == (tile.w * tile.h, haar.tree.tree_size(levels))
        product += int((want[:, 0] > 0).sum())
        none = prim < 0
        assert (nodes[none] == 0).all() and (want[none] == 0).all()
        empty += int(none.sum())
        np.testing.assert_allclose(nodes, want, rtol=0, atol=2e-5 * np.abs(want).max())
        np.testing.assert_allclose(relit, want_relit[:, :3], rtol=1e-4, atol=1e-5 * np.abs(want_relit).max())
        # the coat's share of G, the control variate's tint (0 but on plastic)
        np.testing.assert_allclose(trees.coat_share(), want_relit[:, 3], rtol=1e-3, atol=1e-4)
        side = 1 << levels
        leaves = nodes[:, haar.tree.level_offset(levels):].reshape(-1, side, side)
        np.testing.assert_allclose(nodes[:, 0], leaves.sum(axis=(1, 2)), rtol=1e-5, atol=1e-9 * leaves.max())
    assert empty > 0 and product > 0.3 * width * height


def test_the_trees_hold_the_approximate_frame(bakes):
    """G, the trees' relit value, is the product <T1, f_r> at the trees' texels: near the
    approximate frame's pixel mode on the ball and the floor (its finer walk and cosine
    correction aside), so that the control variate's g is close to the integrand."""
    scene, by_bits, folder = bakes
    frames = view_frames.ViewFrames(by_bits[16], scene)
    conv = converger(frames, texel_light(frames, 4))
    sc = camera_scene(frames)
    tile = vc.tiles_of(36, 20)[0]
    _, relit = conv.tile_trees(sc, tile, 36, 20)[0].read()
    image, _ = frames.frame(EYE, TARGET, width=36, height=20, mode="pixel", tau=0.0)
    d, prim, u, v = centre_rays(frames, sc, tile, 36, 20)
    hit = prim >= 0
    albedo = scene.material_albedo[scene.face_material[prim[hit]]]
    got, want = relit[hit] * albedo, image.reshape(-1, 3)[hit]
    assert np.linalg.norm(got - want) / np.linalg.norm(want) < 0.25


@pytest.mark.parametrize("options", [{}, {"candidates": 8, "coherence": 0.0}, {"control": False, "slots": 2}])
def test_the_kernel_frame_matches_the_numpy_frame(bakes, options):
    """The same frame (the same random numbers: camera rays, directions, candidates) with the
    kernels and with their numpy twins, with the defaults, with every hit whose footprint spreads
    resampled, and without the control variate: nearly every pixel equal, and the images' sums
    within a fraction of their standard error."""
    scene, by_bits, folder = bakes
    frames = view_frames.ViewFrames(by_bits[8], scene)
    a = frames.converge(EYE, TARGET, spp=4, seed=9, **options)
    b = frames.converge(EYE, TARGET, spp=4, seed=9, backend="numpy", **options)
    assert a.stats["backend"] == "opencl" and b.stats["backend"] == "numpy"
    assert a.stats["rays"] == b.stats["rays"] > 0
    assert a.stats["resampled_share"] == b.stats["resampled_share"]
    assert (a.stats["resampled_share"] > 0.5) == bool(options.get("candidates"))
    diff = np.abs(a.image - b.image).max(2)
    assert (diff > 1e-3 * (1 + np.abs(b.image).max(2))).mean() < 0.03, diff.max()
    var = (b.stderr ** 2).sum()
    assert abs((a.image - b.image).sum()) < 0.5 * np.sqrt(var)


def test_trees_are_kept_while_the_camera_stays(bakes, monkeypatch):
    """A camera's first frame builds its trees in scratch buffers and keeps none; the second
    keeps them; the third reads them (the same image for the same seed each time); another eye
    builds them again, in the last camera's buffers (kept at once), another size in new ones;
    with no room for them none is kept, and the image is the same."""
    scene, by_bits, folder = bakes
    monkeypatch.setattr(vc, "TILE_PIXELS", 36 * 8)
    frames = view_frames.ViewFrames(by_bits[16], scene)
    first, second, again = (frames.converge(EYE, TARGET, spp=2, seed=3) for _ in range(3))
    other = frames.converge([2.1, 2.0, 3.0], TARGET, spp=2, seed=3)
    smaller = frames.converge([2.1, 2.0, 3.0], TARGET, width=30, spp=2, seed=3)
    assert first.stats["tiles"] == 3 and first.stats["tiles_kept"] == first.stats["kept_tree_bytes"] == 0
    assert second.stats["tiles_kept"] == 0 and second.stats["kept_tree_bytes"] > 0 and again.stats["tiles_kept"] == 3
    assert first.stats["setup_seconds"] > 0 and again.stats["setup_seconds"] < first.stats["setup_seconds"]
    assert other.stats["tiles_kept"] == 0 and other.stats["kept_tree_bytes"] == again.stats["kept_tree_bytes"]
    assert smaller.stats["tiles_kept"] == smaller.stats["kept_tree_bytes"] == 0
    np.testing.assert_array_equal(first.image, second.image)
    np.testing.assert_array_equal(first.image, again.image)
    assert not np.array_equal(first.image, other.image)
    assert again.stats["rays"] < first.stats["rays"]   # no centre rays
    monkeypatch.setattr(vc, "TREE_CACHE_BYTES", 0)
    tight = view_frames.ViewFrames(by_bits[16], scene)
    once, twice = (tight.converge(EYE, TARGET, spp=2, seed=3) for _ in range(2))
    assert once.stats["kept_tree_bytes"] == twice.stats["tiles_kept"] == 0
    np.testing.assert_array_equal(twice.image, first.image)


def test_bad_backend_is_one_clear_error(bakes):
    scene, by_bits, folder = bakes
    frames = view_frames.ViewFrames(by_bits[16], scene)
    with pytest.raises(wavlight.WavlightError, match="backend"):
        frames.converge(EYE, TARGET, spp=1, backend="cuda")


def test_the_kernel_frame_matches_the_numpy_frame_with_the_bilinear_background(bakes):
    """With background="bilinear" the camera samples that miss see the map's filter in
    converge_shade (BACKGROUND_MODE 1) as in its twin (TexelLight.background); the samples that
    hit are the nearest background's frame's (the same random numbers, the lighting unchanged)."""
    scene, by_bits, folder = bakes
    frames = view_frames.ViewFrames(by_bits[8], scene, background="bilinear")
    a = frames.converge(EYE, TARGET, spp=4, seed=9)
    b = frames.converge(EYE, TARGET, spp=4, seed=9, backend="numpy")
    assert a.stats["background"] == b.stats["background"] == "bilinear"
    diff = np.abs(a.image - b.image).max(2)
    assert (diff > 1e-3 * (1 + np.abs(b.image).max(2))).mean() < 0.03, diff.max()
    assert abs((a.image - b.image).sum()) < 0.5 * np.sqrt((b.stderr ** 2).sum())
    near = view_frames.ViewFrames(by_bits[8], scene).converge(EYE, TARGET, spp=4, seed=9)
    assert near.stats["background"] == "nearest"
    # pixels whose samples all hit: the same numbers (the kernel's miss branch alone differs)
    sc = dataclasses.replace(scene, camera=frames.camera(EYE, TARGET, None))
    x, y = np.meshgrid(np.arange(36), np.arange(20))
    corners = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]], np.float32)
    hit_all = np.ones(36 * 20, bool)
    for c in corners:
        eye, d = wavlight.camera.camera_rays(sc, x.ravel(), y.ravel(), np.tile(c, (36 * 20, 1)), 36, 20)
        prim, _ = frames.tracer.intersect(eye, d)
        hit_all &= prim >= 0
    hit_all = hit_all.reshape(20, 36)
    inner = hit_all.copy()   # and their neighbours' corners too: no silhouette passes between them
    inner[1:] &= hit_all[:-1]
    inner[:-1] &= hit_all[1:]
    inner[:, 1:] &= hit_all[:, :-1]
    inner[:, :-1] &= hit_all[:, 1:]
    hit_all = inner
    assert hit_all.any() and (~hit_all).any()
    np.testing.assert_allclose(a.image[hit_all], near.image[hit_all], rtol=1e-5, atol=1e-6)
    assert not np.allclose(a.image[~hit_all], near.image[~hit_all], rtol=1e-5, atol=1e-6)


def test_the_frame_without_background_is_its_twins_and_drops_the_misses_alone(bakes):
    """With background="none" (the viewer's hidden background) converge_shade's misses
    contribute 0 as in its twin; pixels whose rays all miss are 0, pixels whose samples all hit
    are the nearest background's frame's (the same random numbers), and the sibling frames
    (ViewFrames.with_background) are kept."""
    scene, by_bits, folder = bakes
    frames = view_frames.ViewFrames(by_bits[8], scene)
    hidden = frames.with_background("none")
    assert hidden is frames.with_background("none") and hidden.environment.background == "none"
    assert frames.environment.background == "nearest" and hidden.tracer is frames.tracer
    a = frames.converge(EYE, TARGET, spp=4, seed=9, background="none")
    b = hidden.converge(EYE, TARGET, spp=4, seed=9, backend="numpy")
    assert a.stats["background"] == b.stats["background"] == "none"
    diff = np.abs(a.image - b.image).max(2)
    assert (diff > 1e-3 * (1 + np.abs(b.image).max(2))).mean() < 0.03, diff.max()
    near = frames.converge(EYE, TARGET, spp=4, seed=9)
    sc = dataclasses.replace(scene, camera=frames.camera(EYE, TARGET, None))
    x, y = np.meshgrid(np.arange(36), np.arange(20))
    corners = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]], np.float32)
    hit_all, miss_all = np.ones(36 * 20, bool), np.ones(36 * 20, bool)
    for c in corners:
        eye, d = wavlight.camera.camera_rays(sc, x.ravel(), y.ravel(), np.tile(c, (36 * 20, 1)), 36, 20)
        prim, _ = frames.tracer.intersect(eye, d)
        hit_all &= prim >= 0
        miss_all &= prim < 0
    hit_all, miss_all = hit_all.reshape(20, 36), miss_all.reshape(20, 36)
    for m in (hit_all, miss_all):   # their neighbours' corners too: no silhouette passes between them
        inner = m.copy()
        inner[1:] &= m[:-1]
        inner[:-1] &= m[1:]
        inner[:, 1:] &= m[:, :-1]
        inner[:, :-1] &= m[:, 1:]
        m[...] = inner
    assert hit_all.any() and miss_all.any()
    np.testing.assert_allclose(a.image[hit_all], near.image[hit_all], rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(a.image[miss_all], 0.0)
    assert (near.image[miss_all] > 0).all()
