"""The unbiased relit frame's kernels (kernels/converge.cl) against their numpy twins
(wavlight.relight.converge.tile_trees_reference and shade_reference): each tile's product trees
and relit values, each camera sample's directions, estimates and control variate; the kernel
frame against the numpy frame on the same random numbers; and the trees a ConvergeFrames keeps
while the lighting stays."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import wavlight
from scenes_util import write_lamp_sky
from wavlight import camera, haar
from wavlight.relight import converge as cm


def sphere_on_floor(width, height, ball=None):
    """A glossy sphere over a lambert floor under a sky with a small bright light; width and
    height that are not multiples of the bake's blocks (16) nor of the kernels' lanes (8)."""
    return {"render": {"width": width, "height": height},
            "camera": {"eye": [0.0, 1.5, 3.5], "target": [0.0, 0.5, 0.0], "fov_y": 40.0},
            "environment": {"file": "sky.exr", "rotate_y": 20.0},
            "objects": [{"shape": "sphere", "center": [0.0, 0.6, 0.0], "radius": 0.6, "subdivisions": 3,
                         "material": "ball"},
                        {"shape": "quad", "center": [0.0, 0.0, 0.0], "size": 6.0, "material": "floor"}],
            "materials": {"ball": ball or {"type": "ggx", "albedo": [0.9, 0.8, 0.6], "roughness": 0.3},
                          "floor": {"type": "lambert", "albedo": [0.6, 0.6, 0.6]}}}


@pytest.fixture(scope="module")
def bakes(tmp_path_factory, device):
    """The scene at 36 x 20 pixels (3 x 2 blocks, the last column 4 pixels wide, the last row 4
    tall), baked at 8 and at 16 bits (2^4 x 2^4 texels)."""
    folder = tmp_path_factory.mktemp("maps")
    write_lamp_sky(folder)   # a small bright light
    scene = wavlight.load_dict(sphere_on_floor(36, 20), base_dir=folder)
    out = {bits: wavlight.bake(scene, spp=4, levels=4, terms=256, priority="area", tolerance=1e-3, bits=bits)
           for bits in (8, 16)}
    return scene, out, folder


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("levels", [4, 2])
def test_trees_kernel_equals_its_twin(bakes, bits, levels):
    """converge_trees against tile_trees_reference, tile by tile (a whole block row, and the
    tiles of the image's edges): the pyramids (float32 against float64 inverse transforms) and
    the relit values G; the trees are additive (parent = sum of children, as the warp needs)."""
    scene, by_bits, folder = bakes
    tr = by_bits[bits]
    frames = cm.ConvergeFrames(tr, scene)
    state = frames.lighting(None, 75.0, 1.0, levels)
    prog = frames.program(levels, 2, 0, True)
    assert len(frames.tiles) == 2 and frames.tiles[0].blocks == 3 and frames.tiles[1].h == 4
    skipped = 0
    for tile in frames.tiles:
        nodes, relit = frames._trees(prog, state.device, tile).read()
        scale = frames.tree_scale[tile.y0:tile.y0 + tile.h, tile.x0:tile.x0 + tile.w].reshape(-1)
        want, want_relit = cm.tile_trees_reference(cm.tile_coefficients(tr, tile, levels), state.inside, scale)
        assert nodes.shape == want.shape == (tile.w * tile.h, haar.tree.tree_size(levels))
        assert (want[:, 0] > 0).mean() > 0.3
        empty = scale == 0    # pixels whose bake samples all missed: a root of 0
        assert (nodes[empty] == 0).all() and (want[empty] == 0).all()
        skipped += int(empty.sum())
        np.testing.assert_allclose(nodes, want, rtol=0, atol=2e-5 * np.abs(want).max())
        np.testing.assert_allclose(relit, want_relit, rtol=1e-4, atol=1e-5 * np.abs(want_relit).max())
        side = 1 << levels
        leaves = nodes[:, haar.tree.level_offset(levels):].reshape(-1, side, side)
        np.testing.assert_allclose(nodes[:, 0], leaves.sum(axis=(1, 2)), rtol=1e-5, atol=1e-9 * leaves.max())
    assert skipped > 0


def textured_floor(scene):
    """The same scene (and content hash) with a random 8 x 8 base-colour texture on its floor,
    repeating twice across it (texture coordinates from x and z): the bake's transfer was made
    without it, and the unbiased frame's estimate stays unbiased (its control variate has zero
    mean for any albedo)."""
    rng = np.random.default_rng(9)
    floor = next(k for k, m in enumerate(scene.materials) if m.name == "floor")
    uv = (scene.vertices[:, [0, 2]] / 3.0).astype(np.float32)
    return dataclasses.replace(scene, textures=[rng.uniform(0.2, 1.0, (8, 8, 3)).astype(np.float32)],
                               vertex_uv=uv, materials=[dataclasses.replace(m, texture=0) if k == floor else m
                                                        for k, m in enumerate(scene.materials)])


@pytest.mark.parametrize("ball, candidates, coherence, control, textured", [
    (None, cm.CANDIDATES, cm.COHERENCE, True, False),                      # glossy ball, the defaults
    (None, cm.CANDIDATES, 0.0, True, False),                               # every hit resampled
    ({"type": "phong", "albedo": [0.5, 0.6, 0.7], "exponent": 40.0}, 0, 1.0, False, False),   # no resampling or control
    ({"type": "lambert", "albedo": [0.5, 0.6, 0.7]}, 4, cm.COHERENCE, True, False),
    ({"type": "plastic", "albedo": [0.7, 0.3, 0.1], "alpha": 0.15}, cm.CANDIDATES, cm.COHERENCE, True, False),
    ({"type": "plastic", "albedo": [0.7, 0.3, 0.1], "alpha": 0.15}, cm.CANDIDATES, 0.0, True, False),
    (None, cm.CANDIDATES, cm.COHERENCE, True, True)])                      # a textured floor
def test_shade_kernel_equals_its_twin(bakes, ball, candidates, coherence, control, textured):
    """converge_shade against shade_reference on the same camera rays, trees and Philox numbers:
    the misses' radiance, the control variate's part, every slot's direction and estimate. float32
    against float64 moves a direction across a leaf's or a texel's edge now and then: such
    samples are few, and the means agree."""
    scene, by_bits, folder = bakes
    tr = by_bits[8]
    if ball is not None:   # the same transfer, another material on the ball (the estimate stays unbiased)
        other = wavlight.load_dict(sphere_on_floor(36, 20, ball), base_dir=folder)
        scene = dataclasses.replace(scene, materials=[other.materials[0], *scene.materials[1:]])
    if textured:
        scene = textured_floor(scene)
    frames = cm.ConvergeFrames(tr, scene)
    slots, k, seed = 2, 8, 5
    state = frames.lighting(None, 75.0, 1.0, 4)
    prog = frames.program(4, slots, candidates, control)
    tile = frames.tiles[0]
    trees = frames._trees(prog, state.device, tile)
    nodes, relit = trees.read()
    spread, spread_buf = frames.spread(tile)
    tile_id = cm.CONVERGE_TILES + 3
    d = camera.pass_rays(scene, tr.width, tr.height, seed, tile_id, tile.x0, tile.y0, tile.w, tile.h, k, 0,
                         stratified=True)
    prim, t, bu, bv = frames.tracer.intersect_uv(np.broadcast_to(scene.camera.eye.astype(np.float32), d.shape), d)
    assert frames.tracer.smooth   # the ball's shading normals, interpolated in both
    bary = np.stack([bu, bv], 1)
    shares = (cm.DEFENSIVE, cm.LIGHT_SHARE, coherence)
    got = frames._shade(prog, slots, d, prim, t, k, 0, trees, spread_buf, state.device, shares, seed, tile_id,
                        bary=bary)
    tree = haar.HaarTree.from_pyramids(nodes)
    want = cm.shade_reference(scene, frames.tracer, d, prim, t, k, tree, nodes, relit, spread, state.inside,
                              (seed, tile_id), 0, slots, cm.DEFENSIVE, cm.LIGHT_SHARE, control, candidates, coherence,
                              bary=bary)
    direct, origin, wi, value = (np.asarray(a, np.float64) for a in got)
    hit = prim >= 0
    assert 0.3 < hit.mean() < 1
    np.testing.assert_allclose(direct[~hit], want[0][~hit], rtol=1e-6)
    np.testing.assert_allclose(origin[hit], want[1][hit], rtol=0, atol=1e-5)
    # per slot: the direction where the estimate is not 0, the estimate
    same_dir = np.abs(wi - want[2]).max(1) < 1e-3
    live = np.maximum(value.max(1), want[3].max(1)) > 0
    close = np.abs(value - want[3]).max(1) <= 2e-3 * np.abs(want[3]).max(1) + 1e-6
    assert live[:, hit].mean() > 0.5
    assert (same_dir | ~live)[:, hit].mean() > 0.99 and close[:, hit].mean() > 0.99, (same_dir.mean(), close.mean())
    d_close = np.abs(direct[hit] - want[0][hit]).max(1) <= 2e-3 * np.abs(want[0][hit]).max(1) + 1e-5
    assert d_close.mean() > 0.99
    if not control:
        assert (direct[hit] == 0).all()
    if coherence == 0.0 and candidates:   # no control variate where resampled: every pixel of spread > 0
        chosen = hit & (spread[np.arange(len(d)) // k] > 0)
        assert chosen[hit].mean() > 0.9 and (direct[chosen] == 0).all()
    total_got = direct[hit].sum(0) + value[:, :, hit].sum((0, 2))
    total_want = want[0][hit].sum(0) + want[3][:, :, hit].sum((0, 2))
    se = np.sqrt((want[0][hit] + want[3][:, :, hit].sum(0).T).var(0) * hit.sum())
    assert np.all(np.abs(total_got - total_want) < 0.2 * se + 1e-6), (total_got, total_want, se)


def test_the_kernel_frame_matches_the_numpy_frame(bakes):
    """The same frame (same random numbers: camera rays, directions, candidates) with the kernels
    and with their numpy twins: nearly every pixel equal, and the images' sums within a fraction
    of their standard error."""
    scene, by_bits, folder = bakes
    tr = by_bits[8]
    a = cm.ConvergeFrames(tr, scene).frame(rotate_y=75.0, spp=4, seed=9, levels=4)
    b = cm.ConvergeFrames(tr, scene, backend="numpy").frame(rotate_y=75.0, spp=4, seed=9, levels=4)
    assert a.stats["backend"] == "opencl" and b.stats["backend"] == "numpy"
    assert a.stats["resampled_share"] == b.stats["resampled_share"] > 0
    diff = np.abs(a.image - b.image).max(2)
    assert (diff > 1e-3 * (1 + np.abs(b.image).max(2))).mean() < 0.03, diff.max()
    var = (b.stderr ** 2).sum()
    assert abs((a.image - b.image).sum()) < 0.5 * np.sqrt(var)


def test_trees_are_kept_while_the_lighting_stays(bakes, monkeypatch):
    """A lighting's first frame builds its trees in scratch buffers and keeps none; the second
    builds them again and keeps them; the third reads them (the same image for the same seed
    each time); a frame under another lighting builds them again, in the last one's buffers,
    and keeps them at once; with no room for them none is kept, and the image is the same.
    converge keeps its ConvergeFrames for the next call with the same transfer and scene."""
    scene, by_bits, folder = bakes
    tr = by_bits[16]
    frames = cm.ConvergeFrames(tr, scene)
    first, second, again = (frames.frame(rotate_y=40.0, spp=2, seed=3) for _ in range(3))
    turned = frames.frame(rotate_y=41.0, spp=2, seed=3)
    turned_again = frames.frame(rotate_y=41.0, spp=2, seed=3)
    assert first.stats["tiles_kept"] == first.stats["kept_tree_bytes"] == 0
    assert second.stats["tiles_kept"] == 0 and second.stats["kept_tree_bytes"] > 0
    assert again.stats["tiles_kept"] == len(frames.tiles) == 2
    assert turned.stats["tiles_kept"] == 0 and turned.stats["lighting_seconds"] > 0
    assert turned.stats["kept_tree_bytes"] == again.stats["kept_tree_bytes"]
    assert turned_again.stats["tiles_kept"] == len(frames.tiles)
    np.testing.assert_array_equal(first.image, second.image)
    np.testing.assert_array_equal(first.image, again.image)
    np.testing.assert_array_equal(turned.image, turned_again.image)
    assert not np.array_equal(first.image, turned.image)
    monkeypatch.setattr(cm, "TREE_CACHE_BYTES", 0)
    tight = cm.ConvergeFrames(tr, scene)
    once, twice = (tight.frame(rotate_y=40.0, spp=2, seed=3) for _ in range(2))
    assert once.stats["kept_tree_bytes"] == twice.stats["tiles_kept"] == 0
    np.testing.assert_array_equal(twice.image, first.image)
    one = cm.converge(tr, scene, rotate_y=40.0, spp=2, seed=3)
    two = cm.converge(tr, scene, rotate_y=40.0, spp=2, seed=4)
    assert one.stats["setup_seconds"] > 0 and two.stats["setup_seconds"] == 0 and two.stats["tiles_kept"] == 0
    np.testing.assert_array_equal(one.image, first.image)
    assert two.stats["frame_seconds"] == two.stats["render_seconds"]


def test_spread_kernel_equals_its_twin(bakes):
    """converge_spread against footprint_spread on every tile's fixed grid of rays: the pixels
    no ray or one ray hits have 0, the others the same spread (float32 against float64)."""
    scene, by_bits, folder = bakes
    tr = by_bits[8]
    frames = cm.ConvergeFrames(tr, scene)
    prog = frames.program(4, 2, cm.CANDIDATES, True)
    got, want = [], []
    for tile in frames.tiles:
        d, prim = cm.footprint_rays(scene, frames.tracer, tile.x0, tile.y0, tile.w, tile.h, tr.width, tr.height)
        got.append(frames._shade.spread(prog, d, prim, cm.FOOTPRINT_GRID ** 2)[1])
        want.append(cm.footprint_spread(scene, frames.tracer, tile.x0, tile.y0, tile.w, tile.h, tr.width, tr.height))
        assert got[-1].shape == want[-1].shape == (tile.w * tile.h,)
    got, want = np.concatenate(got), np.concatenate(want)
    assert (want == 0).any() and (want > 0.1).any()
    np.testing.assert_allclose(got, want, rtol=1e-3, atol=2e-3)


@pytest.mark.slow
def test_textured_unbiased_frame_equals_mis(bakes):
    """The unbiased frame of a scene whose floor is textured (the bake made without the texture:
    its control variate has zero mean for any albedo) against mis of the textured scene under the
    same turned map: equal within both standard errors, over 4 x 4 blocks of pixels (near
    Gaussian sums) and over the image."""
    from wavlight.envmap import Environment

    scene, by_bits, folder = bakes
    textured = textured_floor(scene)
    r = cm.ConvergeFrames(by_bits[16], textured).frame(rotate_y=75.0, spp=64, seed=4, levels=4)
    env = textured.environment
    turned = dataclasses.replace(textured, environment=Environment(env.pixels, 1.0, 75.0, env.name))
    ref = wavlight.render_full(turned, spp=256, strategy="mis", seed=11)
    var = r.stderr ** 2 + ref.stderr ** 2
    h, w = r.image.shape[:2]
    blocks = lambda a: a[:h - h % 4, :w - w % 4].reshape(h // 4, 4, w // 4, 4, 3).sum(axis=(1, 3))
    z = blocks(r.image - ref.image) / np.sqrt(blocks(var))
    assert np.abs(z).max() < 4.2, z
    assert abs((r.image - ref.image).sum() / np.sqrt(var.sum())) < 3.3


def test_a_warmed_lighting_gives_the_frame_of_its_trees_built_in_the_frame(bakes):
    """warm (in one thread) makes the lighting's trees that a frame's tile threads then read on
    queues of their own: the frame is the one that builds them itself, for the same seed; prepare
    measures the footprints ahead; a warming stopped at once keeps no tree."""
    scene, by_bits, _ = bakes
    tr = by_bits[8]
    cold = cm.ConvergeFrames(tr, scene, threads=2).frame(rotate_y=70.0, spp=2, seed=5)
    frames = cm.ConvergeFrames(tr, scene, threads=2)
    frames.prepare()
    assert len(frames._spread) == len(frames.tiles)
    assert frames.warm(None, 70.0, stop=lambda: True) == 0
    assert frames.warm(None, 70.0) == len(frames.tiles)
    warm = frames.frame(rotate_y=70.0, spp=2, seed=5)
    assert warm.stats["tiles_kept"] == len(frames.tiles) and cold.stats["tiles_kept"] == 0
    np.testing.assert_array_equal(warm.image, cold.image)
    np.testing.assert_array_equal(warm.stderr, cold.stderr)


# ----------------------------------------------------------------------------- plastic's coat
@pytest.fixture(scope="module")
def plastic_bake(bakes):
    """The scene with a plastic ball and a plastic floor, baked with the coat's transfer."""
    _, _, folder = bakes
    d = sphere_on_floor(36, 20, {"type": "plastic", "albedo": [0.7, 0.3, 0.1], "alpha": 0.15})
    d["materials"]["floor"] = {"type": "plastic", "albedo": [0.3, 0.5, 0.6], "alpha": 0.4, "ior": 1.3}
    scene = wavlight.load_dict(d, base_dir=folder)
    tr = wavlight.bake(scene, spp=4, levels=4, terms=256, priority="area", tolerance=1e-3, bits=8)
    assert tr.header["coat"]
    return scene, tr


@pytest.mark.parametrize("levels", [4, 2])
def test_coat_trees_kernel_equals_its_twin(plastic_bake, levels):
    """converge_trees with COAT against tile_trees_reference with the coat: the trees of
    H + w_p H_coat, G, and the coat's share."""
    scene, tr = plastic_bake
    frames = cm.ConvergeFrames(tr, scene)
    assert frames.coat
    state = frames.lighting(None, 75.0, 1.0, levels)
    prog = frames.program(levels, 2, 0, True)
    weights = cm.coat_weights(tr)
    assert (weights > 0).mean() > 0.3
    for tile in frames.tiles:
        made = frames._trees(prog, state.device, tile)
        nodes, relit = made.read()
        share = made.coat_share()
        scale = frames.tree_scale[tile.y0:tile.y0 + tile.h, tile.x0:tile.x0 + tile.w].reshape(-1)
        w = weights[tile.y0:tile.y0 + tile.h, tile.x0:tile.x0 + tile.w].reshape(-1)
        want, want_relit = cm.tile_trees_reference(cm.tile_coefficients(tr, tile, levels), state.inside, scale,
                                                   (cm.tile_coefficients(tr, tile, levels, coat=True), w))
        assert want_relit.shape[1] == 4 and (want_relit[:, 3] > 0.05).mean() > 0.3
        np.testing.assert_allclose(nodes, want, rtol=0, atol=2e-5 * np.abs(want).max())
        np.testing.assert_allclose(relit, want_relit[:, :3], rtol=1e-4, atol=1e-5 * np.abs(want_relit).max())
        np.testing.assert_allclose(share, want_relit[:, 3], rtol=1e-4, atol=1e-5)
        # the coat adds to the tree: without it, the trees are the transfer's alone
        plain, _ = cm.tile_trees_reference(cm.tile_coefficients(tr, tile, levels), state.inside, scale)
        assert (want[:, 0] > plain[:, 0] * (1 + 1e-3))[w > 0].mean() > 0.5


def test_coat_shade_kernel_equals_its_twin(plastic_bake):
    """converge_shade on plastic with the coat's trees and share against shade_reference."""
    scene, tr = plastic_bake
    frames = cm.ConvergeFrames(tr, scene)
    slots, k, seed = 2, 8, 5
    state = frames.lighting(None, 75.0, 1.0, 4)
    prog = frames.program(4, slots, cm.CANDIDATES, True)
    tile = frames.tiles[0]
    trees = frames._trees(prog, state.device, tile)
    nodes, relit = trees.read()
    relit = np.concatenate([relit, trees.coat_share()[:, None]], 1)
    spread, spread_buf = frames.spread(tile)
    tile_id = cm.CONVERGE_TILES + 3
    d = camera.pass_rays(scene, tr.width, tr.height, seed, tile_id, tile.x0, tile.y0, tile.w, tile.h, k, 0,
                         stratified=True)
    prim, t, bu, bv = frames.tracer.intersect_uv(np.broadcast_to(scene.camera.eye.astype(np.float32), d.shape), d)
    bary = np.stack([bu, bv], 1)
    shares = (cm.DEFENSIVE, cm.LIGHT_SHARE, cm.COHERENCE)
    got = frames._shade(prog, slots, d, prim, t, k, 0, trees, spread_buf, state.device, shares, seed, tile_id,
                        bary=bary)
    want = cm.shade_reference(scene, frames.tracer, d, prim, t, k, haar.HaarTree.from_pyramids(nodes), nodes, relit,
                              spread, state.inside, (seed, tile_id), 0, slots, cm.DEFENSIVE, cm.LIGHT_SHARE, True,
                              cm.CANDIDATES, cm.COHERENCE, bary=bary)
    direct, origin, wi, value = (np.asarray(a, np.float64) for a in got)
    hit = prim >= 0
    same_dir = np.abs(wi - want[2]).max(1) < 1e-3
    live = np.maximum(value.max(1), want[3].max(1)) > 0
    close = np.abs(value - want[3]).max(1) <= 2e-3 * np.abs(want[3]).max(1) + 1e-6
    assert live[:, hit].mean() > 0.5
    assert (same_dir | ~live)[:, hit].mean() > 0.99 and close[:, hit].mean() > 0.99, (same_dir.mean(), close.mean())
    d_close = np.abs(direct[hit] - want[0][hit]).max(1) <= 2e-3 * np.abs(want[0][hit]).max(1) + 1e-5
    assert d_close.mean() > 0.99


def test_the_coat_kernel_frame_matches_the_numpy_frame(plastic_bake):
    scene, tr = plastic_bake
    a = cm.ConvergeFrames(tr, scene).frame(rotate_y=75.0, spp=4, seed=9, levels=4)
    b = cm.ConvergeFrames(tr, scene, backend="numpy").frame(rotate_y=75.0, spp=4, seed=9, levels=4)
    diff = np.abs(a.image - b.image).max(2)
    assert (diff > 1e-3 * (1 + np.abs(b.image).max(2))).mean() < 0.03, diff.max()
    assert abs((a.image - b.image).sum()) < 0.5 * np.sqrt((b.stderr ** 2).sum())
