"""Relighting from precomputed transfer (wavlight.relight): the kernels against their numpy
twins, the sparse product against a dense dot product, the furnace, rotations by whole texels,
the bake file's checks, and the unbiased frame against mis."""
from __future__ import annotations

import os
import threading

import numpy as np
import pytest

import wavlight
from wavlight import bsdfs, cl, warp
from scenes_util import write_lamp_sky, write_raw_image
from wavlight import haar
from wavlight.envmap import Environment
from wavlight.errors import WavlightError
from wavlight.raytrace import RayTracer
from wavlight.relight import bake as bake_mod
from wavlight.relight import frame as frame_mod
from wavlight.relight import lighting, store
from wavlight.relight import converge as converge_mod
from wavlight.relight import mixture
from wavlight.relight.converge import converge


def sphere_on_floor(env, material=None, width=16, height=16, floor=True):
    """A sphere over a lambert floor (or alone) under ``env`` (an [environment] table)."""
    objects = [{"shape": "sphere", "center": [0.0, 0.6, 0.0], "radius": 0.6, "subdivisions": 3, "material": "ball"}]
    if floor:
        objects.append({"shape": "quad", "center": [0.0, 0.0, 0.0], "size": 6.0, "material": "floor"})
    return {"render": {"width": width, "height": height},
            "camera": {"eye": [0.0, 1.5, 3.5], "target": [0.0, 0.5, 0.0], "fov_y": 40.0},
            "environment": env, "objects": objects,
            "materials": {"ball": material or {"type": "ggx", "albedo": [0.9, 0.8, 0.6], "roughness": 0.3},
                          "floor": {"type": "lambert", "albedo": [0.6, 0.6, 0.6]}}}


@pytest.fixture(scope="module")
def maps(tmp_path_factory):
    folder = tmp_path_factory.mktemp("maps")
    write_lamp_sky(folder)   # a small bright light
    write_raw_image(folder / "white.exr", np.ones((16, 32, 3), np.float32))
    write_raw_image(folder / "black.exr", np.zeros((16, 32, 3), np.float32))
    return folder


@pytest.fixture(scope="module")
def shadowed(maps, device):
    """A glossy sphere on a floor under the sky map, its bake (n = 4, all terms) and scene."""
    scene = wavlight.load_dict(sphere_on_floor({"file": "sky.exr", "rotate_y": 20.0}), base_dir=maps)
    transfer = wavlight.bake(scene, spp=4, levels=4, terms=256, priority="area", tolerance=1e-4, bits=16)
    return scene, transfer


# ----------------------------------------------------------------------------- kernels and twins
@pytest.mark.parametrize("points", bake_mod.POINT_CHOICES)
def test_texel_rays_kernel_equals_its_twin(shadowed, points):
    scene, _ = shadowed
    tracer = RayTracer(scene.vertices, scene.faces)
    ps = bake_mod.camera_samples(scene, tracer, 16, 16, 0, 0, 16, 8, 4, 5, 3)
    assert (ps.count >= 1).any() and ps.miss.any()       # hits, groups and misses in the tile
    d, w, pick = bake_mod.texel_rays(ps, 4, 5, 3, points=points)
    d2, w2, pick2 = bake_mod.texel_rays_reference(ps, 4, 5, 3, points=points)
    np.testing.assert_allclose(w, w2, rtol=2e-3, atol=1e-7 * w2.max())
    live = w2 > 0
    agree = (pick == pick2) & (np.abs(d - d2).max(1) < 1e-4)
    assert agree[live].mean() > 0.995                     # a pick differs only at a rounding tie


def test_frame_kernels_equal_their_twins(shadowed):
    _, tr = shadowed
    coeffs = tr.lighting(rotate_y=50.0)
    cols = lighting.select_terms(coeffs, 64, "area")
    values = coeffs.reshape(3, -1)[:, cols].T * 256.0
    s = tr._s
    device = frame_mod.DeviceFrame(s, tr.width, tr.height, tr.blocks[0], tr.spp)
    kernel = device.read(device.product(cols, values))
    twin = frame_mod.image_reference(s["offsets"], s["entry_scale"], s["entry_data"], cols, values, s["albedo"],
                                     tr.blocks[0])
    assert np.abs(twin).max() > 0
    np.testing.assert_allclose(kernel, twin, rtol=1e-5, atol=1e-6 * np.abs(twin).max())
    env = tr.environment()
    a = tr.frame(rotate_y=50.0, terms=64, priority="area")
    b = tr.frame(rotate_y=50.0, terms=64, priority="area", backend="numpy")
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5 * b.max())
    mask = tr._s["background_mask"]
    u0, row = frame_mod.background_lookup(tr._s["background_dir"], env.height)
    twin_bg = frame_mod.background_reference(env.pixels, 50.0, mask, u0, row)
    out = cl.to_device(np.zeros((tr.height, tr.width, 3), np.float32), writable=True)
    device.background(out, env, 50.0)
    kern_bg = device.read(out).reshape(-1, 3)[s["background_pixel"].astype(np.int64)]
    # the same texels; the kernel adds a run of samples in one texel as the texel times their count
    np.testing.assert_allclose(kern_bg, twin_bg, rtol=tr.spp * 2.0 ** -23, atol=0)
    # and both are the map turned by 50 degrees, looked up in the samples' directions
    turned = Environment(env.pixels, 1.0, 50.0)
    dirs = np.asarray(tr._s["background_dir"], np.float64)
    missing = ((mask[:, None] >> np.arange(tr.spp, dtype=np.uint64)) & np.uint64(1)) > 0
    direct = (turned.eval(dirs.reshape(-1, 3)).reshape(len(mask), tr.spp, 3) * missing[..., None]).sum(1) / tr.spp
    assert np.isclose(twin_bg, direct, rtol=1e-5).all(1).mean() > 0.99   # but texel-boundary rounding


def test_sparse_product_equals_the_dense_dot_product(maps, device):
    """With every term and no compression, a frame is a_p sum_t T_p,t L_t of the bake's texel
    transfer, which the twin of the bake computes densely."""
    scene = wavlight.load_dict(sphere_on_floor({"file": "sky.exr"}, width=16, height=16), base_dir=maps)
    tr = wavlight.bake(scene, spp=2, levels=4, terms=256, priority="magnitude", tolerance=1e-6, bits=16, seed=4,
                       points=4)
    tracer = RayTracer(scene.vertices, scene.faces, normals=scene.normals, normal_faces=scene.normal_faces)
    env = scene.environment
    L = lighting.project(env, 4, 75.0)
    image = np.zeros((16, 16, 3))
    for tile in bake_mod._tiles(16, 16)[0]:   # the blocks of the image
        block, x0, y0, w, h = tile
        ps = bake_mod.camera_samples(scene, tracer, 16, 16, x0, y0, w, h, 2, 4, block)
        T, _ = bake_mod.tile_transfer(ps, tracer, 4, 4, block)
        image[y0:y0 + h, x0:x0 + w] = (np.einsum("pij,ijc->pc", T, L) * ps.albedo).reshape(h, w, 3)
    hits = np.asarray(tr._s["albedo"]).sum(-1) > 0
    got = tr.frame(rotate_y=75.0)
    background = np.zeros_like(got)
    bp = np.asarray(tr._s["background_pixel"], np.int64)
    background.reshape(-1, 3)[bp] = frame_mod.background_reference(
        env.pixels, 75.0, tr._s["background_mask"], *frame_mod.background_lookup(tr._s["background_dir"], env.height))
    np.testing.assert_allclose((got - background)[hits], image[hits], rtol=2e-3, atol=1e-4 * image.max())


def test_white_furnace(maps, device):
    """A lambert sphere alone under a constant map: every frame is its albedo times the radiance,
    and the unbiased frame too (within its standard error)."""
    d = sphere_on_floor({"file": "white.exr", "scale": 2.0}, {"type": "lambert", "albedo": [0.5, 0.7, 0.9]},
                        floor=False)
    scene = wavlight.load_dict(d, base_dir=maps)
    expect = np.array([0.5, 0.7, 0.9]) * 2.0
    # one or four points per texel: the texels the horizon cuts leave a quadrature noise of a few 1e-3
    for points, rtol in ((1, 1.5e-2), (4, 6e-3)):
        tr = wavlight.bake(scene, spp=4, levels=5, terms=1024, priority="area", tolerance=1e-4, bits=16,
                           points=points)
        hits = np.asarray(tr._s["albedo"]).sum(-1) > 0
        full = hits & (np.bincount(np.asarray(tr._s["background_pixel"], np.int64), minlength=256)
                       .reshape(16, 16) == 0)
        for rot in (0.0, 33.0):
            img = tr.frame(rotate_y=rot)
            np.testing.assert_allclose(img[full], np.broadcast_to(expect, img[full].shape), rtol=rtol)
            assert abs(img[full].mean(0) / expect - 1).max() < 1e-3
    r = converge(tr, scene, spp=16, seed=2)
    z = (r.image[full] - expect) / np.maximum(r.stderr[full], 1e-6)
    assert np.abs(z).max() < 5 and abs(z.mean()) < 0.5


def test_rotation_by_whole_texels_is_a_rotated_bake(maps, device):
    """Turning the lighting by k texels is a cyclic shift of its texels, and a frame turned so
    equals the frame of the same scene baked with its map turned so (the transfer does not
    depend on the lighting)."""
    env = wavlight.load_dict(sphere_on_floor({"file": "sky.exr"}), base_dir=maps).environment
    for k in (1, 5, 16):
        np.testing.assert_allclose(lighting.project(env, 5, 360.0 * k / 32), np.roll(lighting.project(env, 5, 0.0), -k,
                                   axis=1), rtol=1e-12, atol=0)
    rot = 360.0 * 3 / 16
    kw = dict(spp=2, levels=4, terms=256, priority="area", tolerance=1e-6, bits=16, seed=9)
    a = wavlight.bake(wavlight.load_dict(sphere_on_floor({"file": "sky.exr"}), base_dir=maps), **kw)
    b = wavlight.bake(wavlight.load_dict(sphere_on_floor({"file": "sky.exr", "rotate_y": rot}), base_dir=maps), **kw)
    fa, fb = a.frame(rotate_y=rot), b.frame()
    np.testing.assert_allclose(fa, fb, rtol=1e-3, atol=1e-4 * fb.max())


@pytest.fixture(scope="module")
def turned_mis(shadowed):
    scene, _ = shadowed
    turned = wavlight.load_dict(sphere_on_floor({"file": "sky.exr", "rotate_y": 80.0}),
                                base_dir=os.path.dirname(scene.environment.name))
    return wavlight.render_full(turned, spp=512, strategy="mis", seed=11)


@pytest.mark.parametrize("levels, control, coherence, passes", [
    (converge_mod.PRODUCT_LEVELS, True, converge_mod.COHERENCE, 1), (2, True, converge_mod.COHERENCE, 1),
    (converge_mod.PRODUCT_LEVELS, False, converge_mod.COHERENCE, 1), (converge_mod.PRODUCT_LEVELS, True, 0.0, 1),
    (converge_mod.PRODUCT_LEVELS, True, 0.0, 4)])
def test_unbiased_frame_equals_mis(shadowed, turned_mis, levels, control, coherence, passes, monkeypatch):
    """Against mis of the same scene under the turned map (shadows, a small bright light): equal
    within the standard errors of both; product trees on the bake's texels (n = 4) and on
    coarser ones (their sums, the light placing directions inside them); with the relit frame as
    control variate and without; with every camera sample's directions resampled (coherence 0);
    with the samples taken in four passes (each its own camera samples, directions and
    candidates)."""
    scene, tr = shadowed
    monkeypatch.setattr(converge_mod, "PASS_SAMPLES", tr.width * tr.height * 64 // passes)   # one tile
    r = converge(tr, scene, rotate_y=80.0, spp=64, seed=3, levels=levels, control=control, coherence=coherence)
    assert r.stats["product_levels"] == min(levels, tr.n_levels)
    if coherence == 0.0:
        assert r.stats["resampled_share"] > 0.95, r.stats   # (all but where at most one footprint ray hits)
    ref = turned_mis
    var = r.stderr ** 2 + ref.stderr ** 2
    # 4 x 4 blocks of pixels (sums of independent pixel estimates: near Gaussian where single
    # pixels under a small bright light are not), per channel: 48 z values, Sidak-corrected 1%
    diff = (r.image - ref.image).reshape(4, 4, 4, 4, 3).sum(axis=(1, 3))
    z = diff / np.sqrt(var.reshape(4, 4, 4, 4, 3).sum(axis=(1, 3)))
    assert np.abs(z).max() < 3.9, z
    total = (r.image - ref.image).sum() / np.sqrt(var.sum())
    assert abs(total) < 3.3


def test_control_variate_lowers_the_variance(shadowed):
    """The relit frame as control variate: on the same samples (same seed) the standard errors
    of the diffuse floor's pixels are smaller with it than without, where the transfer's texels
    are fine enough (2^6 x 2^6) to be close to each sample's f cos V (by about a tenth here; the
    benchmarks' scenes gain 15-25% in relMSE)."""
    scene, _ = shadowed
    tr = wavlight.bake(scene, spp=4, levels=6, terms=256, priority="area", tolerance=1e-4, bits=16)
    with_cv = converge(tr, scene, rotate_y=80.0, spp=64, seed=5, control=True)
    without = converge(tr, scene, rotate_y=80.0, spp=64, seed=5, control=False)
    assert "control variate" in with_cv.stats["estimator"] and "control" not in without.stats["estimator"]
    w, h = tr.width, tr.height
    pix = np.arange(w * h)
    o, d = wavlight.camera.camera_rays(scene, pix % w, pix // w, np.full((w * h, 2), 0.5, np.float32), w, h)
    prim, _ = RayTracer(scene.vertices, scene.faces).intersect(o, d)
    floor = (prim >= 0) & (scene.face_material[np.maximum(prim, 0)] == scene.face_material[-1])
    floor = floor.reshape(h, w) & (without.stderr.sum(2) > 0)
    ratio = (with_cv.stderr[floor] ** 2).sum() / (without.stderr[floor] ** 2).sum()
    # the ratio of two variance estimates over ~100 pixels x 64 samples: ~2% noise
    assert floor.sum() > 20 and ratio < 0.95, ratio
    # no lighting share, no control variate (its integral needs the lighting's technique)
    plain = converge(tr, scene, rotate_y=80.0, spp=2, seed=5, light=0.0)
    assert "control" not in plain.stats["estimator"]


@pytest.fixture(scope="module")
def one_tile(shadowed):
    """The shadowed scene's frames (its one tile) under the map turned to 80 degrees, on its
    bake's texels (n = 4) and on 2 x 2 texels (their sums): per level the lighting, the tile's
    coefficients, product pyramids and relit values G from the numpy twin."""
    scene, tr = shadowed
    c = converge_mod
    frames = c.ConvergeFrames(tr, scene, backend="numpy")
    tile = frames.tiles[0]
    assert tr.blocks == (1, 1) and (tile.w, tile.h) == (tr.width, tr.height)   # its rows are the image's pixels
    out = {}
    for levels in (4, 2):
        state = frames.lighting(None, 80.0, 1.0, levels)
        coeffs = c.tile_coefficients(tr, tile, levels)
        scale = frames.hit_scale.reshape(-1)
        nodes, relit = c.tile_trees_reference(coeffs, state.inside, scale)
        out[levels] = (state.inside, coeffs, scale, nodes, relit)
    return scene, tr, frames, out


@pytest.mark.parametrize("levels", [4, 2])
def test_control_variate_integral_is_the_mean_of_its_samples(one_tile, levels):
    """The control variate's g = H+_t / Omega_t L(w) integrates to G, the value the frame adds
    back: leaf by leaf over the sphere (so both use the same texels, measure, rotation and
    colour), and as E[g / pdf] over the mixture's directions for pixels of the floor and of the
    sphere (one camera ray each, 8 x 4096 directions). G itself equals the quadrature
    sum_t max(c H_t, 0) L_t over the inverse transform of the pixel's coefficients, and the
    trees' leaves are gl_t max(c H_t, 0), so that g reads H+_t from them."""
    scene, tr, frames, by_level = one_tile
    c = converge_mod
    inside, coeffs, scale, nodes, G = by_level[levels]
    n = inside.n
    side = 1 << n
    h = np.maximum(haar.inverse(coeffs.astype(np.float64)) * scale[:, None, None], 0.0)
    quadrature = np.einsum("pij,ijc->pc", h, inside.texel_radiance.reshape(side, side, 3))
    np.testing.assert_allclose(G, quadrature, rtol=1e-9, atol=1e-12 * np.abs(quadrature).max())
    leaves = nodes[:, haar.tree.level_offset(n):].reshape(-1, side, side)
    np.testing.assert_allclose(leaves, inside.leaf_masses()[None] * h, rtol=1e-5, atol=1e-7 * leaves.max())
    # g is constant on each piece of a leaf (the 2 x 2 map pixels a turned leaf overlaps): the
    # pieces hold the leaf's exact projection, and g's integral, piece by piece, is G
    count = 1 << inside.top
    row, col = np.divmod(np.arange(count * count), count)
    leaf_angles = lighting.texel_solid_angles(inside.top)[row]
    held = np.zeros((len(row), 3))
    integral = {p: np.zeros(3) for p in (8, 100, 200)}
    for r in (0, 1):
        for k in (0, 1):
            wc = inside.col_share[col] if k == 0 else 1.0 - inside.col_share[col]
            wr = inside.row_angle_share[row] if r == 0 else 1.0 - inside.row_angle_share[row]
            fu = inside.col_share[col] / 2 if k == 0 else (1.0 + inside.col_share[col]) / 2
            fv = inside.row_share[row] / 2 if r == 0 else (1.0 + inside.row_share[row]) / 2
            uv = np.stack([(col + fu) / count, (row + fv) / count], 1)
            angle = leaf_angles * wc * wr
            held += inside.radiance(uv) * (wc * wr)[:, None]
            for p in integral:
                g = c.transfer_from_trees(nodes, inside, np.full(len(uv), p), uv)[:, None] * inside.radiance(uv)
                integral[p] += (g * angle[:, None]).sum(0)
    np.testing.assert_allclose(held, inside.rgb.reshape(-1, 3), rtol=1e-6, atol=1e-9 * inside.rgb.max())
    for p in integral:
        np.testing.assert_allclose(integral[p], G[p], rtol=1e-5)
    w, h_ = tr.width, tr.height
    every = np.arange(w * h_)
    tracer = frames.tracer
    o, d = wavlight.camera.camera_rays(scene, every % w, every // w, np.full((w * h_, 2), 0.5, np.float32), w, h_)
    seen = np.flatnonzero(tracer.intersect(o, d)[0] >= 0)
    sel = seen[np.linspace(0, len(seen) - 1, 6).astype(int)]    # sphere and floor pixels
    assert len(np.unique(scene.face_material[tracer.intersect(o[sel], d[sel])[0]])) == 2
    trees = haar.HaarTree.from_pyramids(nodes[sel])
    spp, rounds = 4096, 8
    px, py = np.repeat(sel % w, spp), np.repeat(sel // w, spp)
    eye, d = wavlight.camera.camera_rays(scene, px, py, np.full((len(px), 2), 0.5, np.float32), w, h_)
    prim, t = tracer.intersect(eye, d)
    hit = np.flatnonzero(prim >= 0)
    nrm, _, _ = tracer.surface(scene.camera.eye, d[hit], t[hit], prim[hit])
    nrm = nrm.astype(np.float64)
    s_ax, t_ax = warp.frame(nrm)
    wo = warp.to_local(-d[hit].astype(np.float64), s_ax, t_ax, nrm)
    mat = scene.face_material[prim[hit]]
    has_p = trees.integral[hit // spp] > 0
    alpha = np.where(has_p, c.DEFENSIVE, 1.0 - c.LIGHT_SHARE)
    terms = []
    for k in range(rounds):
        u = wavlight.rng.uniforms(17, k, wavlight.rng.CONVERGE_DIRECTIONS[0], 0, len(d))
        direction, _, pdf = c.mixture_directions(trees, inside, u, hit, spp, has_p, alpha, scene.material_kind[mat],
                                                 scene.material_param[mat], wo, (s_ax, t_ax, nrm), c.LIGHT_SHARE,
                                                 with_pdf=True)
        uv = c.world_to_square(direction)
        g = c.transfer_from_trees(nodes[sel], inside, hit // spp, uv)[:, None] * inside.radiance(uv)
        terms.append(np.where((pdf > 0)[:, None], g / np.where(pdf > 0, pdf, 1.0)[:, None], 0.0))
    terms = np.concatenate(terms)
    pixel = np.tile(hit // spp, rounds)
    assert len(np.unique(pixel)) == len(sel)
    for i in range(len(sel)):
        x = terms[pixel == i]
        mean, se = x.mean(0), x.std(0) / np.sqrt(len(x))
        z = (mean - G[sel[i]]) / np.maximum(se, 1e-12 * np.abs(G[sel[i]]).max())
        assert np.abs(z).max() < 4.0, (sel[i], mean, G[sel[i]], z)


@pytest.mark.slow
def test_resampled_directions_are_unbiased(one_tile):
    """The resampled estimate equals the mixture's, camera sample by camera sample: pixels of the
    sphere and of the floor, each with 2048 camera samples through its centre (one shading point
    per pixel: their estimates are of one integral); per pixel the mean of 4 x 2048 resampled
    estimates (every sample resampled: coherence 0) equals the mean of 4 x 2048 mixture
    estimates (never: coherence inf, no control variate) within their standard errors, with one
    pick and with four (systematic) picks among the candidates (numpy twin shade_reference, the
    shadow rays traced; a resampling weighted by the candidates' sum over 15 instead of 16 is 7%
    off and fails)."""
    scene, tr, frames, by_level = one_tile
    c = converge_mod
    inside, coeffs, scale, nodes, G = by_level[4]
    w, h = tr.width, tr.height
    every = np.arange(w * h)
    o, d = wavlight.camera.camera_rays(scene, every % w, every // w, np.full((w * h, 2), 0.5, np.float32), w, h)
    tracer = frames.tracer
    prim = tracer.intersect(o, d)[0]
    ball, floor = (np.flatnonzero(prim >= 0)[scene.face_material[prim[prim >= 0]] == k] for k in (0, 1))
    sel = np.concatenate([ball[np.linspace(0, len(ball) - 1, 4).astype(int)], floor[[0, len(floor) // 2]]])
    spp = 2048
    px, py = np.repeat(sel % w, spp), np.repeat(sel // w, spp)
    eye, d = wavlight.camera.camera_rays(scene, px, py, np.full((len(px), 2), 0.5, np.float32), w, h)
    prim, t = tracer.intersect(eye, d)
    assert (prim >= 0).all()
    trees = haar.HaarTree.from_pyramids(nodes[sel])
    spread = np.ones(len(sel))
    runs = {}
    for label, slots, coherence in (("mixture", 1, np.inf), ("one pick", 1, 0.0), ("four picks", 4, 0.0)):
        values = []
        for k in range(4):
            out = c.shade_reference(scene, tracer, d, prim, t, spp, trees, nodes[sel], G[sel], spread, inside, (23, k),
                                    0, slots, control=False, coherence=coherence)
            values.append(c.visible_sum(tracer, *out)[0])
        runs[label] = np.concatenate(values)
    pixels = np.tile(np.arange(len(d)) // spp, 4)
    for i in range(len(sel)):
        a = runs["mixture"][pixels == i]
        for label in ("one pick", "four picks"):
            b = runs[label][pixels == i]
            se = np.sqrt(a.var(0) / len(a) + b.var(0) / len(b))
            z = (b.mean(0) - a.mean(0)) / np.maximum(se, 1e-12 * np.abs(a.mean(0)).max())
            assert np.abs(z).max() < 4.5, (i, label, a.mean(0), b.mean(0), z)


def test_resampling_target_is_positive_where_the_integrand_is():
    """The target p = Y(L) [(f cos)^a T^(1 - a) + b f cos + c T] is positive wherever f cos L is
    (T may be 0 where the bake's rays missed a direction), 0 where L or both f cos and T are."""
    fcos = np.array([1.0, 1.0, 0.0, 0.0, 2.0])
    radiance = np.array([[1.0, 1.0, 1.0], [0.5, 0.0, 0.0], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]])
    transfer = np.array([0.0, 3.0, 2.0, 0.0, 5.0])
    p = mixture.resampling_target(fcos, radiance, transfer)
    assert p[0] > 0 and p[1] > 0 and p[2] > 0 and p[3] == 0 and p[4] == 0
    c = mixture
    expect = (1.0 ** c.LOBE_POWER * 3.0 ** (1 - c.LOBE_POWER) + c.TARGET_BSDF + 3.0 * c.TARGET_TRANSFER)
    assert np.isclose(p[1], wavlight.envmap.luminance(radiance[1:2])[0] * expect)


def test_footprint_spread(shadowed):
    """The spread of a pixel's mirror directions: 0 where no ray of the pixel hits, about the
    pixel's own angular size on the flat floor (the view turns across the pixel), and wide
    where a pixel holds the sphere's rim and the floor."""
    scene, tr = shadowed
    c = converge_mod
    w, h = tr.width, tr.height
    tracer = RayTracer(scene.vertices, scene.faces, threads=1)
    spread = c.footprint_spread(scene, tracer, 0, 0, w, h, w, h)
    assert spread.shape == (w * h,) and np.isfinite(spread).all() and (spread >= 0).all()
    g = c.FOOTPRINT_GRID
    every = np.repeat(np.arange(w * h), g * g)
    sub = np.tile((np.stack(np.meshgrid(np.arange(g), np.arange(g)), -1).reshape(-1, 2) + 0.5) / g, (w * h, 1))
    o, d = wavlight.camera.camera_rays(scene, every % w, every // w, sub.astype(np.float32), w, h)
    mat = np.where((prim := tracer.intersect(o, d)[0]) >= 0, scene.face_material[np.maximum(prim, 0)], -1)
    mat = mat.reshape(w * h, g * g)
    pixel_angle = np.radians(scene.camera.fov_y) / h
    none = (mat < 0).sum(1) >= g * g - 1
    flat = (mat == 1).all(1)
    mixed = (mat == 0).any(1) & (mat == 1).any(1)
    assert none.any() and flat.any() and mixed.any()
    assert (spread[none] == 0).all()
    assert (spread[flat] < 2 * pixel_angle).all() and (spread[flat] > 0.1 * pixel_angle).all()
    assert np.median(spread[mixed]) > 4 * pixel_angle


@pytest.mark.parametrize("rotate_y", [0.0, 80.0, 3.0])
def test_points_inside_a_texel_follow_the_map_pixels(rotate_y):
    """A map black but for one pixel, turned by a fraction of a map column or by whole ones: the
    points the lighting places in that pixel's texel all land on it (a leaf overlapping it and
    a black pixel gives the black part nothing), the density factor is the sampler's, and
    without ``map_pixels`` (uniform in the leaf) about half of them miss it."""
    pixels = np.zeros((32, 64, 3), np.float32)
    pixels[9, 21] = 50.0
    env = Environment(pixels, 1.0, 0.0, "one pixel")
    inside = mixture.TexelLight(env, 3, rotate_y)
    u = np.random.default_rng(1).random((20000, 3))
    uv = inside.sample_light(u[:, 0], u[:, 1], u[:, 2])
    assert (inside.radiance(uv)[:, 0] == 50.0).all()
    turned = Environment(pixels, 1.0, rotate_y, "one pixel")
    assert (turned.eval(mixture.square_to_world(uv))[:, 0] == 50.0).mean() > 0.999
    # the density is the sampler's: E[1 / pdf] is the area of its support, the pixel's 1 / (64 x 32)
    inv = 1.0 / inside.light_pdf(uv)
    assert abs(inv.mean() * 64 * 32 - 1.0) < 5 * inv.std() / np.sqrt(len(inv)) * 64 * 32 + 1e-12
    plain = mixture.TexelLight(env, 3, rotate_y, map_pixels=False)
    hits = (turned.eval(mixture.square_to_world(plain.sample_light(u[:, 0], u[:, 1], u[:, 2])))[:, 0] == 50.0)
    if rotate_y % (360.0 / 64) == 0:
        assert hits.all()
    else:
        assert 0.05 < hits.mean() < 0.95


@pytest.mark.parametrize("shape, levels, rotate_y", [((32, 64), 3, 0.0), ((32, 64), 3, 37.3), ((37, 100), 2, -200.7),
                                                     ((8, 16), 6, 123.4)])
def test_leaf_radiance_from_the_map_pieces_is_the_projectors_integral(shape, levels, rotate_y):
    """TexelLight's leaf radiance, made from each leaf's 2 x 2 pieces of map pixels, is the
    projector's exact integral of the turned map over the leaf (maps of any size, leaves as wide
    as a map pixel or narrower), to float64 rounding."""
    pixels = np.random.default_rng(7).gamma(0.5, 2.0, shape + (3,)).astype(np.float32)
    env = Environment(pixels, 1.0, 0.0, "noise")
    inside = mixture.TexelLight(env, levels, rotate_y)
    assert inside.projector is None
    want = lighting.Projector(env, inside.top)(rotate_y)
    np.testing.assert_allclose(inside.rgb, want, rtol=1e-10, atol=1e-12 * want.max())


def test_a_map_wider_than_the_leaves_takes_the_projectors_leaf_radiance():
    """A map wider than 2^11 pixels, whose leaves span more than two of its columns, takes its
    leaf radiance from the projector."""
    wide = Environment(np.random.default_rng(8).gamma(0.5, 2.0, (1, 2100, 3)).astype(np.float32), 1.0, 0.0, "wide")
    far = mixture.TexelLight(wide, 3, 37.3)
    assert far.top == 11 and far.projector is not None and far.projector.n_levels == 11
    np.testing.assert_array_equal(far.rgb, far.projector(37.3))


# ----------------------------------------------------------------------------- the bake file
def test_save_load_and_checks(shadowed, tmp_path):
    _, tr = shadowed
    path = tmp_path / "t.wlt"
    tr.save(path)
    again = wavlight.Transfer.load(path)
    np.testing.assert_array_equal(again.frame(rotate_y=10.0), tr.frame(rotate_y=10.0))
    raw = path.read_bytes()
    (tmp_path / "short.wlt").write_bytes(raw[:-100])
    with pytest.raises(WavlightError, match="truncated"):
        wavlight.Transfer.load(tmp_path / "short.wlt")
    header = store.read_header(str(path))
    offset = header["data_offset"] + header["sections"]["entry_data"]["offset"] + 5
    damaged = bytearray(raw)
    damaged[offset] ^= 0x55
    (tmp_path / "bad.wlt").write_bytes(bytes(damaged))
    with pytest.raises(WavlightError, match="damaged.*entry_data"):
        wavlight.Transfer.load(tmp_path / "bad.wlt")
    (tmp_path / "junk.wlt").write_bytes(b"not a bake file at all" * 10)
    with pytest.raises(WavlightError, match="not a wavlight bake file"):
        wavlight.Transfer.load(tmp_path / "junk.wlt")
    future = raw.replace(f'"version": {store.FORMAT_VERSION}'.encode(), b'"version": 9', 1)
    (tmp_path / "future.wlt").write_bytes(future)
    with pytest.raises(WavlightError, match="version 9"):
        wavlight.Transfer.load(tmp_path / "future.wlt")
    with pytest.raises(WavlightError, match="no such bake file"):
        wavlight.Transfer.load(tmp_path / "missing.wlt")


def test_frame_arguments(shadowed):
    _, tr = shadowed
    for kw, message in ((dict(terms=0), "terms"), (dict(rotate_y=float("nan")), "rotate_y"),
                        (dict(scale=-1.0), "scale"), (dict(priority="loud"), "priority"),
                        (dict(env=3), "env must be")):
        with pytest.raises(WavlightError, match=message):
            tr.frame(**kw)


def test_an_interrupted_bake_leaves_no_file(maps, tmp_path, device):
    scene = wavlight.load_dict(sphere_on_floor({"file": "sky.exr"}), base_dir=maps)

    def stop(done, total, rays, seconds):
        if done == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        wavlight.bake(scene, tmp_path / "out.wlt", spp=1, levels=3, terms=16, priority="area", progress=stop,
                      threads=1)
    assert os.listdir(tmp_path) == []


def test_a_changed_scene_is_refused_for_the_unbiased_frame(maps, tmp_path, device):
    d = sphere_on_floor({"file": "sky.exr"})
    scene = wavlight.load_dict(d, base_dir=maps)
    tr = wavlight.bake(scene, spp=1, levels=3, terms=16, priority="area")
    d["materials"]["ball"]["roughness"] = 0.5
    with pytest.raises(WavlightError, match="changed since"):
        converge(tr, wavlight.load_dict(d, base_dir=maps), spp=1)
    with pytest.raises(WavlightError, match="given as a dict"):
        converge(tr, None, spp=1)


def test_lighting_priorities_and_terms():
    rng = np.random.default_rng(1)
    c = haar.forward(rng.random((3, 8, 8)))
    for kind in ("magnitude", "area"):
        cols = lighting.select_terms(c, 10, kind)
        assert len(cols) == 10 and np.all(np.diff(cols) > 0)
    with pytest.raises(WavlightError):
        lighting.select_terms(c, 10, "transfer")          # needs the transfer's rms
    assert len(lighting.select_terms(np.zeros((3, 8, 8)), 10, "area")) == 0


# ----------------------------------------------------------------------------- the pilot's choices
def test_texel_points_follow_the_lobe():
    """Coarser texels and narrower lobes get at least as many points per texel; a lobe spanning
    LOBE_SPACINGS point spacings or more at one point per texel keeps one."""
    def scene_of(kind, roughness):   # what texel_points reads of a scene: its materials
        from types import SimpleNamespace
        code = {"lambert": bsdfs.LAMBERT, "ggx": bsdfs.GGX}[kind]
        return SimpleNamespace(materials=[SimpleNamespace(kind=code, param=roughness or 0.0)])
    for scene in (scene_of("lambert", None), scene_of("ggx", 0.3), scene_of("ggx", 0.05)):
        pts = [bake_mod.texel_points(scene, n) for n in range(8, 1, -1)]
        assert pts == sorted(pts) and set(pts) <= set(bake_mod.POINT_CHOICES)
        lobe = min(bsdfs.lobe_width(m.kind, m.param) for m in scene.materials)
        for n, q in zip(range(8, 1, -1), pts):
            spacing = np.pi / (1 << n) / bake_mod.POINT_GRID[q]
            assert spacing * bake_mod.LOBE_SPACINGS <= lobe or q == 16
            if q > 1:   # one grid step fewer would not have been enough
                assert 2 * spacing * bake_mod.LOBE_SPACINGS > lobe
    narrow = [bake_mod.texel_points(scene_of("ggx", 0.05), n) for n in range(8, 1, -1)]
    wide = [bake_mod.texel_points(scene_of("lambert", None), n) for n in range(8, 1, -1)]
    assert all(a >= b for a, b in zip(narrow, wide))


@pytest.mark.slow
def test_the_pilot_meets_its_own_criteria(maps, device):
    """The pilot's choices: n the fewest levels whose bias and noise fit half the tolerance
    (else the least of them), S the fewest samples keeping them there, K the fewest terms within
    the margin of the share; a looser tolerance never asks for more levels; given values are kept."""
    scene = wavlight.load_dict(sphere_on_floor({"file": "sky.exr", "rotate_y": 20.0}), base_dir=maps)
    chosen = []
    for tol in (0.5, 0.05, 0.005):
        m = bake_mod.choose_model(scene, tol, None, 0, width=16, height=16)
        p = m["pilot"]
        n, S, K = m["n_levels"], m["spp"], m["terms"]
        bias = {int(k): v for k, v in p["level_error"].items()}
        noise = {int(k): v for k, v in p["noise_at_pilot_spp"].items()}
        assert p["spp"] == bake_mod.MAX_SAMPLES and S in bake_mod.SPP_CHOICES
        both = {k: np.hypot(bias[k], bake_mod.NOISE_MARGIN * noise[k]) for k in noise}
        fits = [k for k, e in both.items() if e <= tol / 2 + 1e-5]
        assert n == (min(fits) if fits else min(both, key=both.get))
        bound = lambda s: np.hypot(bias[n], bake_mod.NOISE_MARGIN * noise[n] * np.sqrt(64 / s))   # noqa: E731
        ok = [s for s in bake_mod.SPP_CHOICES if bound(s) <= tol / 2 + 1e-5]
        assert S == (ok[0] if ok else bake_mod.SPP_CHOICES[-1])
        assert p["noise"] == pytest.approx(noise[n] * np.sqrt(64 / S), rel=1e-3, abs=1e-5)
        terms = {int(k): v for k, v in p["term_error"].items()}
        within = [k for k, e in terms.items() if e <= m["share"] * bake_mod.TERM_MARGIN + 1e-5]
        assert K == (within[0] if within else max(terms))
        chosen.append((S, n, K))
    levels = [n for _, n, _ in chosen]
    assert levels == sorted(levels)                          # a tighter tolerance never takes fewer levels
    kept = bake_mod.choose_model(scene, 0.05, 8, 0, levels=4, width=16, height=16)
    assert kept["spp"] == 8 and kept["n_levels"] == 4 and kept["pilot"]["spp"] == 8


def test_coarser_texels_are_the_top_left_coefficients():
    """The product trees of a bake finer than PRODUCT_LEVELS use the transform of its texels
    summed 2^(n-m) x 2^(n-m): the top-left 2^m x 2^m coefficients times 4^(n - m)."""
    texels = np.random.default_rng(5).random((3, 32, 32))
    for m in (1, 3, 4):
        k = 1 << (5 - m)
        summed = texels.reshape(3, 1 << m, k, 1 << m, k).sum(axis=(2, 4))
        np.testing.assert_allclose(haar.forward(summed), haar.forward(texels)[:, :1 << m, :1 << m] * 4.0 ** (5 - m),
                                   rtol=1e-12, atol=1e-12)


def test_the_pilot_at_few_levels_and_given_points(maps, device):
    """Levels below the pilot's coarsest (2, 3) and points given: the pilot measures at those
    levels and with those points, and a bake made with them has every choice."""
    scene = wavlight.load_dict(sphere_on_floor({"file": "sky.exr", "rotate_y": 20.0}), base_dir=maps)
    for levels in (2, 3):
        m = bake_mod.choose_model(scene, 0.05, None, 0, levels=levels, points=1, width=16, height=16)
        assert m["n_levels"] == levels and m["spp"] in bake_mod.SPP_CHOICES
        assert m["terms"] <= 4 ** levels and str(levels) in m["pilot"]["noise_at_pilot_spp"]
    tr = wavlight.bake(scene, levels=3, points=1, terms=16, priority="area")
    assert tr.n_levels == 3 and tr.spp in bake_mod.SPP_CHOICES and np.isfinite(tr.frame(rotate_y=10.0)).all()


def test_mixture_shares_are_checked(shadowed):
    scene, tr = shadowed
    for defensive, light in ((0.6, 0.5), (0.0, 1.0), (-0.1, 0.1), (0.1, float("nan"))):
        with pytest.raises(WavlightError):
            converge(tr, scene, spp=1, defensive=defensive, light=light)
    for bad in ({"candidates": -1}, {"candidates": converge_mod.MAX_CANDIDATES + 1}, {"coherence": -0.1},
                {"coherence": float("inf")}, {"slots": 0}):
        with pytest.raises(WavlightError):
            converge(tr, scene, spp=1, **bad)
    plain = converge(tr, scene, spp=1, candidates=0)
    assert plain.stats["resampled_share"] == 0 and "resampled" not in plain.stats["estimator"]


def test_experiment_bake_samples_within_the_bakes_own_limit():
    from wavlight.evaluation.spec import RELIGHT_KEYS
    assert RELIGHT_KEYS["bake_spp"][3] == bake_mod.MAX_SAMPLES


def test_a_bake_without_an_output_leaves_no_file(maps, device, monkeypatch, tmp_path):
    """wavlight.bake(..., output=None) and its pilots write temporary files that are removed as
    soon as they are read: the Transfer holds the file in memory (frames and save work), and the
    temporary folder is as before, also while the Transfer lives."""
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    scene = wavlight.load_dict(sphere_on_floor({"file": "sky.exr"}, width=8, height=8), base_dir=maps)
    tr = wavlight.bake(scene, spp=2, levels=3, terms=64, priority="area")
    assert os.listdir(tmp_path) == []
    image = tr.frame()
    assert image.shape == (8, 8, 3) and np.isfinite(image).all()
    tr.save(tmp_path / "kept.wlt")
    assert os.listdir(tmp_path) == ["kept.wlt"]
    assert np.array_equal(wavlight.Transfer.load(tmp_path / "kept.wlt").frame(), image)


class Failing:
    """A stand-in for a module's camera_rays whose ``fail_at``-th call raises (as a Ctrl-C stops
    the caller's wait); ``after`` counts the calls begun after it, in any thread."""

    def __init__(self, real, fail_at: int):
        self.real, self.fail_at, self.calls, self.after = real, fail_at, 0, 0
        self.lock = threading.Lock()

    def __call__(self, *args, **kwargs):
        with self.lock:
            self.calls += 1
            if self.calls > self.fail_at:
                self.after += 1
            elif self.calls == self.fail_at:
                raise RuntimeError("stopped")
        return self.real(*args, **kwargs)


def test_an_error_stops_the_unbiased_frame_at_the_next_pass(maps, monkeypatch):
    """A block of the unbiased frame that fails (as Ctrl-C stops the command's wait): the blocks
    under way stop at their next pass instead of running their remaining spp (`frame --spp 20000`
    went on for minutes after Ctrl-C)."""
    scene = wavlight.load_dict(sphere_on_floor({"file": "sky.exr"}, width=32, height=16), base_dir=maps)
    tr = wavlight.bake(scene, spp=4, levels=3)
    assert tr.blocks == (2, 1)
    failing = Failing(converge_mod.camera.pass_rays, fail_at=3)
    monkeypatch.setattr(converge_mod.camera, "pass_rays", failing)
    with pytest.raises(RuntimeError, match="stopped"):
        converge(tr, scene, spp=converge_mod.PASS_SPP * 40, threads=2)
    assert failing.after <= 2, failing.after   # 40 passes a block: up to 38 more without the stop
