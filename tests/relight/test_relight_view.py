"""Frames from a moving camera (wavlight.relight.view_frames): the product kernel against its numpy twin
and against the dense sum over texels, the BRDF factor against wavlight.bsdfs, the surface
cache's lattice, the bake's texels as integrals, the unbiased frame against mis from another
camera, the command line and its one-line errors."""
from __future__ import annotations

import dataclasses
import json
import os

import numpy as np
import pytest

import wavlight
from scenes_util import check_estimates, toml_text, write_lamp_sky
from test_relight_cli import one_error_line, run
from wavlight import animation, bsdfs, haar
from wavlight.relight import lighting, surface_cache, view_bake, view_frames, view_walk

EYE, TARGET = [2.0, 2.0, 3.0], [0.0, 0.5, 0.0]


def scene_dict(camera=None, material=None):
    return {"render": {"width": 24, "height": 24},
            "camera": camera or {"eye": [0.0, 1.5, 3.5], "target": [0.0, 0.5, 0.0], "fov_y": 40.0},
            "environment": {"file": "sky.exr", "rotate_y": 20.0},
            "objects": [{"shape": "sphere", "center": [0.0, 0.6, 0.0], "radius": 0.6, "subdivisions": 3,
                         "material": "ball"},
                        {"shape": "quad", "center": [0.0, 0.0, 0.0], "size": 6.0, "material": "floor"}],
            "materials": {"ball": material or {"type": "ggx", "albedo": [0.9, 0.8, 0.6], "roughness": 0.3},
                          "floor": {"type": "lambert", "albedo": [0.6, 0.6, 0.6]}}}


@pytest.fixture(scope="module")
def baked(tmp_path_factory, device):
    """A glossy sphere on a floor under a sky with a small bright light, its view bake (16 x 16
    texels, 16 bits, nearly lossless) and scene file."""
    folder = tmp_path_factory.mktemp("relight_view")
    write_lamp_sky(folder)   # a small bright light
    (folder / "scene.toml").write_text(toml_text(scene_dict()))
    scene = wavlight.load_scene(folder / "scene.toml")
    tr = wavlight.bake(scene, folder / "ball.wlt", vary="view", levels=4, density=400, tolerance=1e-3, bits=16)
    return folder, scene, tr


def test_brdf_factor_is_f_cos_over_cos():
    rng = np.random.default_rng(0)
    wi, wo = rng.normal(size=(2, 4000, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]) + 1e-3, np.abs(wo[:, 2]) + 1e-3
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    for kind, param in ((bsdfs.LAMBERT, 0.0), (bsdfs.PHONG, 20.0), (bsdfs.GGX, 0.2), (bsdfs.GGX, 0.6)):
        got = view_walk.brdf_reference(np.full(len(wi), kind), np.full(len(wi), param), wi, wo) * wi[:, 2]
        np.testing.assert_allclose(got, bsdfs.eval_cos(kind, np.full(len(wi), param), wi, wo), rtol=1e-9, atol=1e-12)


def test_product_kernel_equals_its_twin(baked):
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    points = np.arange(0, len(frames.position), 5)
    kinds = frames.kind_of[frames.material[points]]
    assert (kinds == bsdfs.GGX).sum() > 100 and (kinds == bsdfs.LAMBERT).sum() > 100
    for eye, refine, mass in ((EYE, 0.25, view_walk.MASS), ([-1.0, 0.8, 2.0], 0.1, view_walk.MASS), (EYE, 0.25, 0.0),
                              (EYE, 0.4, 1e-3)):
        a, na, *_ = frames.products(points, eye, refine, mass=mass)
        b, nb, *_ = frames.products(points, eye, refine, backend="numpy", mass=mass)
        assert np.abs(b).max() > 0
        close = np.isclose(a, b, rtol=1e-4, atol=1e-6 * np.abs(b).max()).all(1)
        assert close.mean() > 0.995 and (na == nb).mean() > 0.99   # but a threshold within rounding
        np.testing.assert_allclose(a, b, rtol=2e-2, atol=1e-4 * np.abs(b).max())
    # and both frames
    fa, _ = frames.frame(EYE, TARGET)
    fb, _ = frames.frame(EYE, TARGET, backend="numpy")
    np.testing.assert_allclose(fa, fb, rtol=2e-2, atol=1e-4 * fb.max())


def test_product_kernel_equals_its_twin_for_every_kind(baked):
    """The walk's BRDF (phong, ggx smooth and rough, lambert) on the same points, kernel against
    product_reference, with the points' own normals and views."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    points, _, nrm, wo = frames._point_items(np.arange(2, len(frames.position), 11), EYE)
    rng = np.random.default_rng(7)
    choice = rng.integers(0, 4, len(points))
    kind = np.array([bsdfs.PHONG, bsdfs.GGX, bsdfs.GGX, bsdfs.LAMBERT])[choice]
    param = np.array([20.0, 0.05, 0.6, 0.0])[choice]
    device = view_walk.ViewDevice(tr)
    s = tr._s
    for refine in (0.2, 0.4):
        a, na = device.products(points, kind, param, nrm, wo, refine)
        b, nb = view_walk.product_reference(s["offsets"], s["entry_scale"], s["entry_data"], tr.n_levels, points, kind,
                                       param, nrm, wo, refine)
        assert np.abs(b).max() > 0 and (na == nb).mean() > 0.99
        for k in range(4):
            sel = choice == k
            close = np.isclose(a[sel], b[sel], rtol=1e-4, atol=1e-6 * np.abs(b).max()).all(1)
            assert close.mean() > 0.99, (k, close.mean())
        np.testing.assert_allclose(a, b, rtol=2e-2, atol=1e-4 * np.abs(b).max())


def pixel_items(frames, eye, target, size=24):
    """The pixel mode's items of a size x size frame: cache points, weights, face normals, ray
    directions and materials of the hits."""
    scene = frames.scene
    cam = frames.camera(eye, target)
    pix = np.arange(size * size)
    o, d = wavlight.camera.camera_rays(dataclasses.replace(scene, camera=cam), pix % size,
                                       pix // size, np.full((len(pix), 2), 0.5, np.float32), size, size)
    prim, t, u, v = frames.tracer.intersect_uv(o, d)
    hit = prim >= 0
    ids, w, fn = frames.hit_points(cam.eye, d[hit], prim[hit], t[hit], (u[hit], v[hit]))
    ok = w.sum(1) > 0
    return ids[ok], w[ok], fn[ok], d[hit][ok], scene.face_material[prim[hit][ok]]


@pytest.mark.parametrize("tau", [0.0, view_frames.TAU])
def test_pixel_kernel_equals_its_twin(baked, tau):
    """Per pixel: the blend of three points' T1 with the face normal and the pixel's view, the
    kernel (K = 3) against product_reference, with and without the cosine's correction."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    ids, w, fn, d, mat = pixel_items(frames, EYE, TARGET)
    kinds = frames.kind_of[mat]
    assert (kinds == bsdfs.GGX).sum() > 50 and (kinds == bsdfs.LAMBERT).sum() > 50
    a, na, *_ = frames.pixel_products(ids, w, fn, d, mat, tau=tau)
    b, nb, *_ = frames.pixel_products(ids, w, fn, d, mat, tau=tau, backend="numpy")
    assert np.abs(b).max() > 0
    close = np.isclose(a, b, rtol=1e-4, atol=1e-6 * np.abs(b).max()).all(1)
    assert close.mean() > 0.99 and (na == nb).mean() > 0.98
    np.testing.assert_allclose(a, b, rtol=2e-2, atol=1e-3 * np.abs(b).max())
    fa, _ = frames.frame(EYE, TARGET, mode="pixel", tau=tau)
    fb, _ = frames.frame(EYE, TARGET, mode="pixel", tau=tau, backend="numpy")
    np.testing.assert_allclose(fa, fb, rtol=2e-2, atol=1e-3 * fb.max())


@pytest.mark.parametrize("mode", view_frames.MODES)
def test_supersampled_frame_is_the_finer_frame_box_filtered(baked, mode, monkeypatch):
    """S x S rays per pixel through its sub-pixels' centres: the frame at S times the size,
    averaged over S x S blocks; on the device and in numpy, in chunks of rays that do not divide
    the frame."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    monkeypatch.setattr(view_frames, "CHUNK_PIXELS", 7)   # 28 rays: 3 pixels of 9 rays per chunk
    for backend in ("opencl", "numpy"):
        fine, _ = frames.frame(EYE, TARGET, width=30, height=18, mode=mode, backend=backend)
        got, st = frames.frame(EYE, TARGET, width=10, height=6, mode=mode, backend=backend, supersample=3)
        assert st["supersample"] == 3
        np.testing.assert_allclose(got, fine.reshape(6, 3, 10, 3, 3).mean((1, 3)), rtol=1e-5, atol=1e-6 * fine.max())


def test_mass_steps_round_the_square_root_up_to_a_power_of_two():
    """k with 2^k >= sqrt(share) > 2^(k - 1) (share > 1), capped at MASS_STEPS; 0 for shares up to
    1 and NaN, MASS_STEPS for infinity (as the kernel's float32 bits give them)."""
    share = np.array([0.0, 0.5, 1.0, np.nextafter(np.float32(1), np.float32(2)), 4.0, np.nextafter(np.float32(4), 8),
                      16.0, 17.0, 1e30, np.inf, np.nan], np.float32)
    want = [0, 0, 0, 1, 1, 2, 2, 3, view_walk.MASS_STEPS, view_walk.MASS_STEPS, 0]
    assert view_walk.mass_steps(share).tolist() == want
    rng = np.random.default_rng(5)
    x = np.exp(rng.uniform(0.0, 12.0, 1000)).astype(np.float32)
    k = view_walk.mass_steps(x)
    g = 2.0 ** k
    assert np.all((g >= np.sqrt(x.astype(np.float64)) * (1 - 1e-7)) | (k == view_walk.MASS_STEPS))
    assert np.all((g / 2 < np.sqrt(x.astype(np.float64))) | (k == 0))


def test_pixel_walk_of_one_point_is_the_point_walk(baked):
    """An item of one cache point (weights 1, 0, 0) shaded with the point's normal and view is
    the point mode's product, the correction on or off (rho = 1 where n = m)."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    points = np.arange(1, len(frames.position), 7)
    wo = np.asarray(EYE) - frames.position[points]
    wo = view_walk.lifted_view(frames.normal[points], wo / np.linalg.norm(wo, axis=1, keepdims=True))
    ids = np.stack([points, points[::-1], points], 1)
    w = np.tile([1.0, 0.0, 0.0], (len(points), 1))
    want, nw, *_ = frames.products(points, EYE, backend="numpy")
    for tau in (0.0, view_frames.TAU):
        got, ng, *_ = frames.pixel_products(ids, w, frames.normal[points], -wo, frames.material[points], tau=tau,
                                        backend="numpy")
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-9 * np.abs(want).max())
        assert np.array_equal(ng, nw)


def frame_rays(frames, eye, target, size):
    """Camera rays through the pixel centres of a size x size frame and their hits."""
    cam = frames.camera(eye, target)
    pix = np.arange(size * size)
    o, d = wavlight.camera.camera_rays(dataclasses.replace(frames.scene, camera=cam), pix % size, pix // size,
                                       np.full((len(pix), 2), 0.5, np.float32), size, size)
    prim, t, u, v = frames.tracer.intersect_uv(o, d)
    return cam, d, prim, t, u, v


@pytest.mark.parametrize("eye", [EYE, [0.0, -1.0, 3.5]])
def test_lookup_kernel_equals_hit_points(baked, eye):
    """view_lookup against its numpy twin ViewFrames.hit_points: the same cache points and weights
    per hit (all but rays within rounding of a lattice triangle's border), zero weights on misses
    (and, from below the floor, on the faces' backs), and the points of weight > 0."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    cam, d, prim, t, u, v = frame_rays(frames, eye, TARGET, 48)
    fd = view_walk.FrameDevice(frames, view_walk.ViewDevice(tr))
    queue = wavlight.cl.thread_queue()
    ids_b, w_b, _, _, points = fd.lookup(prim, u, v, d, queue)
    ids = wavlight.cl.read(ids_b, (len(prim), 3), np.uint32, queue).astype(np.int64)
    w = wavlight.cl.read(w_b, (len(prim), 3), np.float32, queue)
    hit = np.flatnonzero(prim >= 0)
    want_ids, want_w, _ = frames.hit_points(cam.eye, d[hit], prim[hit], t[hit], (u[hit], v[hit]))
    assert len(hit) > 500 and np.all(w[prim < 0] == 0)
    same = (ids[hit] == want_ids).all(1)
    assert same.mean() > 0.995
    np.testing.assert_allclose(w[hit][same], want_w[same], rtol=1e-6, atol=1e-7)
    # where the triangle differs the blend is the same point of the face
    pos = frames.position
    np.testing.assert_allclose(np.einsum("ij,ijk->ik", w[hit], pos[ids[hit]]),
                               np.einsum("ij,ijk->ik", want_w, pos[want_ids]), atol=1e-4)
    used = np.unique(want_ids[want_w > 0])
    assert np.array_equal(points, used) or np.setxor1d(points, used).size <= 3 * (~same).sum()
    if eye[1] < 0:
        assert not len(points) and np.all(w == 0)


def test_assemble_kernel_equals_its_twin(baked):
    """view_assemble against the numpy frame's assembly: hits blend their points' products times
    the albedo; misses take the environment's texel of Environment.eval, the same texel for
    directions anywhere (poles, the seam, texel borders: float angles, double near a border)."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    cam, d, prim, t, u, v = frame_rays(frames, EYE, TARGET, 40)
    rng = np.random.default_rng(5)
    env = frames.environment
    # directions on texel borders, the poles and the seam, and random ones; as misses
    uv = np.concatenate([rng.integers(0, [env.width + 1, env.height + 1], (3000, 2)) / [env.width, env.height],
                         rng.random((3000, 2)), [[0.0, 0.0], [0.5, 1.0], [0.0, 0.5], [1.0, 0.5], [0.25, 0.5]]])
    extra = env.square_to_world(np.clip(uv, 0.0, 1.0)).astype(np.float32)
    extra /= np.linalg.norm(extra, axis=1, keepdims=True)
    extra = np.concatenate([extra, rng.normal(size=(3000, 3)).astype(np.float32),
                            np.float32([[0, 1, 0], [0, -1, 0], [0, 0, -1], [-1e-8, 0.5, -1]])])
    extra /= np.linalg.norm(extra, axis=1, keepdims=True)
    d = np.concatenate([d, extra]).astype(np.float32)
    prim = np.concatenate([prim, np.full(len(extra), -1, np.int32)])
    u, v = np.concatenate([u, np.zeros(len(extra), np.float32)]), np.concatenate([v, np.zeros(len(extra), np.float32)])
    device = view_walk.ViewDevice(tr)
    fd = view_walk.FrameDevice(frames, device)
    queue = wavlight.cl.thread_queue()
    ids_b, w_b, prim_b, dir_b, points = fd.lookup(prim, u, v, d, queue)
    B = np.abs(rng.normal(size=(len(points), 3))).astype(np.float32)
    got = fd.assemble(len(prim), prim_b, ids_b, w_b, dir_b, points, wavlight.cl.to_device(B), queue)
    ids = wavlight.cl.read(ids_b, (len(prim), 3), np.uint32, queue).astype(np.int64)
    w = wavlight.cl.read(w_b, (len(prim), 3), np.float32, queue)
    miss, hit = prim < 0, np.flatnonzero(prim >= 0)
    same = (got[miss] == env.eval(d[miss].astype(np.float64))).all(1)
    # exact with double precision near the borders; in float only a border's neighbour may differ
    assert same.all() if view_walk.device_has_doubles() else same.mean() > 0.98
    at = np.full(len(frames.position), len(points), np.int64)
    at[points] = np.arange(len(points))
    rows = np.concatenate([B, np.zeros((1, 3), np.float32)])
    want = np.einsum("ij,ijc->ic", w[hit], rows[at[ids[hit]]]) * frames.albedo_of[scene.face_material[prim[hit]]]
    np.testing.assert_allclose(got[hit], want, rtol=1e-5, atol=1e-7)


def test_assemble_kernel_filters_the_background_as_its_twin(baked):
    """With background="bilinear" view_assemble's misses are Environment.eval_background's
    filter (the seam, the poles, texel borders and random directions), and the frames of both
    backends agree; the hits are the nearest background's frame's."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene, background="bilinear")
    env = frames.environment
    assert env.background == "bilinear" and scene.environment.background == "nearest"
    rng = np.random.default_rng(9)
    uv = np.concatenate([rng.integers(0, [env.width + 1, env.height + 1], (2000, 2)) / [env.width, env.height],
                         rng.random((2000, 2)), [[0.0, 0.0], [0.5, 1.0], [0.0, 0.5], [1.0, 0.5]]])
    d = env.square_to_world(np.clip(uv, 0.0, 1.0)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    prim = np.full(len(d), -1, np.int32)
    zeros = np.zeros(len(d), np.float32)
    device = view_walk.ViewDevice(tr)
    fd = view_walk.FrameDevice(frames, device)
    queue = wavlight.cl.thread_queue()
    ids_b, w_b, prim_b, dir_b, points = fd.lookup(prim, zeros, zeros, d, queue)
    got = fd.assemble(len(prim), prim_b, ids_b, w_b, dir_b, points, wavlight.cl.to_device(np.zeros((1, 3),
                                                                                                  np.float32)), queue)
    want = env.eval_background(d.astype(np.float64))
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5 * float(np.abs(want).max()))
    fa, _ = frames.frame(EYE, TARGET)
    fb, _ = frames.frame(EYE, TARGET, backend="numpy")
    np.testing.assert_allclose(fa, fb, rtol=2e-2, atol=1e-4 * fb.max())
    near, _ = view_frames.ViewFrames(tr, scene).frame(EYE, TARGET)
    differs = (np.asarray(near) != np.asarray(fa)).any(-1)
    assert 0 < differs.mean() < 1   # the sky differs, the surfaces do not


def test_assemble_kernel_hides_the_background_as_its_twin(baked):
    """With background="none" view_assemble's misses are 0 (Environment.eval_background's
    twin), the frames of both backends agree, and the hits are the nearest background's frame's."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    hidden = frames.with_background("none")
    env = hidden.environment
    rng = np.random.default_rng(11)
    d = rng.normal(size=(500, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    prim = np.full(len(d), -1, np.int32)
    zeros = np.zeros(len(d), np.float32)
    fd = view_walk.FrameDevice(hidden, view_walk.ViewDevice(tr))
    queue = wavlight.cl.thread_queue()
    ids_b, w_b, prim_b, dir_b, points = fd.lookup(prim, zeros, zeros, d, queue)
    got = fd.assemble(len(prim), prim_b, ids_b, w_b, dir_b, points,
                      wavlight.cl.to_device(np.zeros((1, 3), np.float32)), queue)
    np.testing.assert_array_equal(got, env.eval_background(d.astype(np.float64)))
    np.testing.assert_array_equal(got, 0.0)
    fa, _ = frames.frame(EYE, TARGET, background="none")
    fb, _ = hidden.frame(EYE, TARGET, backend="numpy")
    np.testing.assert_allclose(fa, fb, rtol=2e-2, atol=1e-4 * fb.max())
    near, _ = frames.frame(EYE, TARGET)
    sky = (np.asarray(fa) == 0).all(-1)
    assert 0 < sky.mean() < 1 and (near[sky] > 0).any()
    np.testing.assert_array_equal(fa[~sky], near[~sky])   # the surfaces are the same numbers


def test_walk_to_the_texels_is_the_dense_sum(baked):
    """With refine -> 0 every node is refined down to the texels: B = sum_t T1_t f_r(w_t), the
    stored coefficients inverted to texels and summed densely."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    points = np.arange(3, len(frames.position), 97)
    side = 1 << tr.n_levels
    s = tr._s
    coeffs = view_walk._coefficients(s["offsets"], s["entry_scale"], s["entry_data"], points, np.arange(side * side))
    T = haar.inverse(coeffs.reshape(len(points), 3, side, side))                        # (I, 3, N, N) texels
    wo = np.asarray(EYE) - frames.position[points]
    wo = view_walk.lifted_view(frames.normal[points], wo / np.linalg.norm(wo, axis=1, keepdims=True))
    mat = frames.material[points]
    dirs = lighting.texel_directions(tr.n_levels).reshape(-1, 3)
    n = frames.normal[points]
    s_ax, t_ax = wavlight.warp.frame(n)
    wl = np.stack([dirs @ a.T for a in (s_ax, t_ax, n)], -1).transpose(1, 0, 2)          # (I, N^2, 3)
    wol = np.stack([np.einsum("ij,ij->i", wo, a) for a in (s_ax, t_ax, n)], 1)
    f = view_walk.brdf_reference(np.repeat(frames.kind_of[mat], side * side),
                                 np.repeat(frames.param_of[mat], side * side), wl.reshape(-1, 3),
                                 np.repeat(wol, side * side, axis=0)).reshape(len(points), -1)
    dense = np.einsum("icn,in->ic", T.reshape(len(points), 3, -1), f)
    got, nodes, *_ = frames.products(points, EYE, refine=1e-4)
    assert nodes.max() > side * side / 2                                                  # the texels were reached
    np.testing.assert_allclose(got, dense, rtol=2e-3, atol=1e-5 * np.abs(dense).max())
    # the default walk is close to it, with far fewer nodes
    approx, few, *_ = frames.products(points, EYE)
    glossy = frames.kind_of[mat] == bsdfs.GGX
    err = np.linalg.norm(approx[glossy] - dense[glossy]) / np.linalg.norm(dense[glossy])
    assert err < 0.03 and few[glossy].mean() < nodes[glossy].mean() * 0.8, (err, few[glossy].mean())
    # the bright light holds much of T1's mass in a few nodes: refining them (mass) is closer to
    # the dense sum than the walk by the lobe alone with as many nodes or more
    for refine in (view_walk.REFINE, view_walk.REFINE / 2, view_walk.REFINE / 4):
        plain, plain_nodes, *_ = frames.products(points, EYE, refine=refine, mass=0.0)
        if plain_nodes[glossy].mean() >= few[glossy].mean():
            break
    assert plain_nodes[glossy].mean() >= few[glossy].mean(), (plain_nodes[glossy].mean(), few[glossy].mean())
    err_plain = np.linalg.norm(plain[glossy] - dense[glossy]) / np.linalg.norm(dense[glossy])
    assert err < err_plain, (err, err_plain)


def test_lattice_finds_the_hit_and_its_points(baked):
    """A hit's three cache points and weights reproduce the hit point (flat faces), all of its
    own object, and the cache covers every face."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    rng = np.random.default_rng(1)
    face = rng.integers(0, len(scene.faces), 5000)
    face[:200] = len(scene.faces) - 1                                                      # the floor, finely divided
    u, v = rng.random((2, 5000))
    flip = u + v > 1
    u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
    tri = scene.vertices[scene.faces[face]].astype(np.float64)
    p = tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])
    uu, vv = surface_cache.barycentric(scene.vertices, scene.faces, face, p)
    np.testing.assert_allclose(np.stack([uu, vv], 1), np.stack([u, v], 1), atol=1e-5)
    ids, w = surface_cache.lattice_points(frames.face_k, frames.face_base, frames.lattice, face, uu, vv)
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ijk->ik", w, frames.position[ids]), p, atol=1e-5)
    assert np.all(frames.material[ids] == scene.face_material[face][:, None])
    # about the density asked for, on the floor
    floor = frames.material == scene.face_material[-1]
    assert 0.8 < floor.sum() / (36.0 * 400) < 1.5


def test_bake_texels_are_integrals_of_L_V_cos(baked):
    """On open floor far from the sphere, G = T1 / L is the texel's integral of max(cos, 0) over
    its solid angle (not a point value): the texels of the upper hemisphere sum to pi."""
    _, scene, tr = baked
    cache = surface_cache.build_cache(scene, 400)
    far = np.flatnonzero((np.abs(cache.position[:, 0]) > 2.5) & (np.abs(cache.position[:, 2]) > 2.5))[:256]
    sub = surface_cache.SurfaceCache(cache.position[far], cache.normal[far], cache.material[far], cache.face[far],
                            cache.face_k, cache.face_base, cache.lattice, cache.spacing, cache.density)
    n = 4
    light = lighting.project(scene.environment, n)
    s = view_bake._Settings(n, 1e-3, 16, 0, "opencl", 4, light)
    tracer = wavlight.raytrace.RayTracer(scene.vertices, scene.faces)
    T1, rays = view_bake.point_transfer(sub, tracer, s, 0)
    G = T1[:, 0] / light[None, :, :, 0]
    side = 1 << n
    z = np.cos(np.pi * np.arange(side + 1) / side)
    exact = np.pi / side * (np.maximum(z[:-1], 0) ** 2 - np.maximum(z[1:], 0) ** 2)   # dphi / 2 (sin^2 theta)
    np.testing.assert_allclose(G.sum((1, 2)), np.pi, rtol=4e-2)           # one jittered ray per texel
    assert abs(G.sum((1, 2)).mean() / np.pi - 1) < 1e-2
    np.testing.assert_allclose(G.mean(0).sum(1) / side, exact, rtol=2e-2, atol=1e-3)
    assert rays <= 256 * side * side // 2 + 256 * side                                      # no rays below the horizon


def test_unbiased_frame_equals_mis_from_another_camera(baked):
    folder, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    spp = 64
    r = frames.converge(EYE, TARGET, spp=spp, seed=3)
    moved = wavlight.load_dict(scene_dict({"eye": EYE, "target": TARGET, "fov_y": 40.0}), base_dir=folder)
    ref = wavlight.render_full(moved, spp=512, strategy="mis", seed=11)
    se = np.sqrt(r.stderr.astype(np.float64) ** 2 + ref.stderr.astype(np.float64) ** 2)
    # 4 x 4 blocks of pixels, per channel (sums of independent pixel estimates: near Gaussian where
    # single pixels that see the small bright light through a glossy lobe are not), Sidak 1%
    # over the 108 block values, and the whole image
    check_estimates(r.image, se, ref.image, np.ones((24, 24), bool), spp, per_pixel=False,
                    label="view converge vs mis")
    diff = (r.image.astype(np.float64) - ref.image).reshape(6, 4, 6, 4, 3).sum(axis=(1, 3))
    z = diff / np.sqrt((se ** 2).reshape(6, 4, 6, 4, 3).sum(axis=(1, 3)))
    assert np.abs(z).max() < 4.0, z
    hits = ref.stderr.max(-1) > 0
    # the product makes the estimate better than the BSDF alone would: per sample below mis's
    assert np.median(r.stderr[hits] * np.sqrt(spp)) < np.median(ref.stderr[hits] * np.sqrt(512))
    # and the approximate frame is near it
    for mode in view_frames.MODES:
        image, _ = frames.frame(EYE, TARGET, mode=mode)
        assert np.linalg.norm(image - ref.image) / np.linalg.norm(ref.image) < 0.12, mode


def test_frames_of_one_map_share_its_lighting_and_make_the_same_frame(baked):
    """A new ViewFrames of the same map takes the lighting inside the texels made for the last one
    (the same object and device tables; a copy of the map's pixels finds it too), a turned map
    gets its own, and a frame with the kept lighting is the one made with a new one."""
    from wavlight.relight import view_converge
    from wavlight.relight.mixture import TexelLight

    _, scene, tr = baked
    first, second = view_frames.ViewFrames(tr, scene), view_frames.ViewFrames(tr, scene)
    env = first.environment
    m = min(first.n, view_frames.PRODUCT_LEVELS)
    inside = first._texel_light()
    assert second._texel_light() is inside
    assert view_frames.texel_light(env.with_background("nearest"), m) == (inside, True)
    assert view_converge.device_lighting(inside) is view_converge.device_lighting(second._texel_light())
    turned, was_kept = view_frames.texel_light(wavlight.envmap.Environment(env.pixels.copy(), 1.0, env.rotate_y + 30.0), m)
    assert turned is not inside and not was_kept
    made = TexelLight(wavlight.envmap.Environment(env.pixels, 1.0, 0.0), m, env.rotate_y)
    for name, table in made.tables().items():
        np.testing.assert_array_equal(np.asarray(table), np.asarray(inside.tables()[name]), err_msg=name)
    kept = second.converge(EYE, TARGET, width=12, height=12, spp=2, seed=5)
    view_frames._LIGHTS.clear()
    fresh = view_frames.ViewFrames(tr, scene)
    assert fresh._texel_light() is not inside
    again = fresh.converge(EYE, TARGET, width=12, height=12, spp=2, seed=5)
    assert kept.stats["lighting_kept"] and not again.stats["lighting_kept"]
    np.testing.assert_array_equal(kept.image, again.image)


def test_a_camera_that_sees_only_uncached_sides_gets_a_frame(baked):
    """From below the floor every hit is a face's back, which has no cache: the frame is black
    there and the environment where rays miss, in both modes (never an error)."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    for mode in view_frames.MODES:
        image, _ = frames.frame([0.0, -1.0, 3.5], [0.0, 0.5, 0.0], mode=mode)
        assert np.all(np.isfinite(image)) and image.min() >= 0 and image.max() > 0, mode


# ----------------------------------------------------------------------------- the command line
def test_command_line(baked, tmp_path):
    folder, _, _ = baked
    out = tmp_path / "v.wlt"
    r = run("bake", folder / "scene.toml", "-o", out, "--vary", "view", "--levels", 3, "--density", 100, "--json")
    assert r.exit_code == 0, r.output
    stats = json.loads(r.stdout)
    assert stats["file_bytes"] == os.path.getsize(out) and stats["bake_seconds"] > 0 and stats["rays_per_second"] > 0
    assert stats["model"]["vary"] == "view" and stats["model"]["n_levels"] == 3 and stats["cache"]["points"] > 0
    r = run("frame", out, "--eye", *EYE, "--target", *TARGET, "--width", 20, "--height", 16, "-o", tmp_path / "f.png",
            "--json")
    assert r.exit_code == 0, r.output
    st = json.loads(r.stdout)
    assert st["frame_seconds"] > 0 and st["frames_per_second"] > 0 and (st["width"], st["height"]) == (20, 16)
    assert all(st[k] == v for k, v in view_frames.STILL.items())   # a written frame's defaults
    r = run("frame", out, "--eye", *EYE, "--target", *TARGET, "--width", 20, "--height", 16, "--tau", 0.2,
            "--supersample", 2, "--mass", 0, "-o", tmp_path / "p.png", "--json")
    assert r.exit_code == 0, r.output
    st = json.loads(r.stdout)
    assert (st["mode"], st["tau"], st["supersample"], st["mass"]) == ("pixel", 0.2, 2, 0.0)
    assert (tmp_path / "p.png").exists()
    r = run("frame", out, "--eye", *EYE, "--target", *TARGET, "--width", 20, "--height", 16, "--mode", "point",
            "-o", tmp_path / "q.png", "--json")
    assert r.exit_code == 0, r.output
    st = json.loads(r.stdout)
    assert (st["mode"], st["supersample"]) == ("point", 1)   # the viewer's frame
    r = run("frame", out, "--orbit", 3, "-o", tmp_path / "orbit", "--quiet")
    assert r.exit_code == 0, r.output
    moving = ["orbit.png", *(["orbit.mp4"] if animation.has_mp4() else [])]
    assert sorted(os.listdir(tmp_path / "orbit")) == sorted(["frame-0000.png", "frame-0001.png", "frame-0002.png",
                                                             *moving])
    r = run("frame", out, "--eye", *EYE, "--spp", 2, "-o", tmp_path / "c.exr", "--json")
    assert r.exit_code == 0 and json.loads(r.stdout)["spp"] == 2 and (tmp_path / "c.exr").exists(), r.output


def test_help_gives_the_walks_defaults():
    """``wavlight frame --help`` states the walk's defaults as the library has them."""
    r = run("frame", "--help")
    text = " ".join(r.output.split())
    assert r.exit_code == 0
    assert f"Default: {view_walk.REFINE:g}." in text and f"Default: {view_walk.MASS:g}." in text, text


@pytest.mark.parametrize("args, words", [
    (("--rotate-y", 30), ("varies the view", "--rotate-y")),
    (("--env", "sky.exr"), ("varies the view", "--env")),
    (("--translate", 0, 0, 0), ("varies the view", "--translate")),
    (("--eye", "nan", 0, 0), ("--eye", "finite")),
    (("--eye", 1, "inf", 0), ("--eye", "finite")),
    (("--eye", 0, 0.5, 0, "--target", 0, 0.5, 0), ("same point",)),
    (("--fov", 0), ("--fov",)),
    (("--mode", "point", "--tau", 0.1), ("--tau", "--mode pixel")),
    (("--mode", "pixel", "--spp", 2), ("--mode", "--spp")),
    (("--supersample", 2, "--spp", 2), ("--supersample", "--spp")),
    (("--mass", 0.1, "--spp", 2), ("--mass", "--spp")),
    (("--supersample", 0), ("--supersample",)),
])
def test_view_bake_bad_input(baked, tmp_path, args, words):
    folder, _, tr = baked
    args = tuple(folder / a if a == "sky.exr" else a for a in args)
    r = run("frame", tr.path, *args, "-o", tmp_path / "g.png")
    one_error_line(r, *words)
    assert not (tmp_path / "g.png").exists()


def test_camera_flags_on_other_bakes(baked, tmp_path):
    folder, _, _ = baked
    lit = tmp_path / "lit.wlt"
    assert run("bake", folder / "scene.toml", "-o", lit, "--spp", 1, "--levels", 3, "--terms", 16,
               "--priority", "area", "-q").exit_code == 0
    for args in (("--eye", 1, 1, 1), ("--orbit", 4)):
        r = run("frame", lit, *args, "-o", tmp_path / "g.png")
        one_error_line(r, "varies the lighting", args[0])
        assert not (tmp_path / "g.png").exists()
    d = scene_dict()
    d["objects"][0]["name"] = "ball"
    (folder / "named.toml").write_text(toml_text(d))
    ob = tmp_path / "ob.wlt"
    assert run("bake", folder / "named.toml", "-o", ob, "--spp", 1, "--levels", 3, "--terms", 16, "--priority", "area",
               "--vary", "object", "--object", "ball", "--static-spp", 2, "-q").exit_code == 0
    r = run("frame", ob, "--eye", 1, 1, 1, "-o", tmp_path / "g.png")
    one_error_line(r, "varies an object", "--eye")
    r = run("bake", folder / "scene.toml", "-o", tmp_path / "x.wlt", "--density", 10)
    one_error_line(r, "--density", "--vary view")
    with pytest.raises(wavlight.WavlightError, match="varies the view"):
        wavlight.Transfer.load(baked[2].path).frame()


def test_an_error_stops_the_unbiased_frame_at_the_next_pass(baked, monkeypatch):
    """A tile of the unbiased frame that fails (as Ctrl-C stops the command's wait): the tiles
    under way stop at their next pass instead of running their remaining spp."""
    from test_relight import Failing
    from wavlight.relight import view_converge

    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    monkeypatch.setattr(view_converge, "TILE_PIXELS", 48 * 16)   # two tiles
    failing = Failing(view_converge.pass_rays, fail_at=3)        # after both tiles' first passes
    monkeypatch.setattr(view_converge, "pass_rays", failing)
    with pytest.raises(RuntimeError, match="stopped"):
        frames.converge(EYE, TARGET, width=48, height=32, spp=view_frames.PASS_SPP * 12, threads=2)
    assert failing.after <= 2, failing.after   # 12 passes a tile: up to 10 more without the stop


def test_a_frames_size_is_the_given_one_else_the_bakes(baked):
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    assert frames.size() == (tr.width, tr.height) and frames.size(40, None) == (40, tr.height)
    with pytest.raises(wavlight.WavlightError, match="width"):
        frames.size(0, 8)
