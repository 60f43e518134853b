"""A view bake of a textured scene (wavlight.relight.view_bake, view_frames, view_converge): a
GLB's floor with a base-colour texture of stripes and a gold sphere, and a textured pyramid. The
cache's points carry the textured albedo, view_assemble takes the texture at the hit as its twin
does, the frames of both backends agree, and the unbiased frame agrees with mis from another
camera (the approximate one is near it)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import wavlight
from assets_util import write_glb, write_textured_pyramid
from scenes_util import check_estimates, toml_text, write_lamp_sky
from wavlight import textures
from wavlight.relight import view_frames, view_walk

EYE, TARGET = [1.5, 2.2, 3.2], [0.0, 0.3, 0.0]


def scene_dict(camera=None):
    return {"render": {"width": 24, "height": 24},
            "camera": camera or {"eye": [0.0, 1.8, 3.8], "target": [0.0, 0.3, 0.0], "fov_y": 45.0},
            "environment": {"file": "sky.exr", "rotate_y": 20.0},
            "objects": [{"mesh": "a.glb"}, {"mesh": "p.obj", "scale": 0.4, "translate": [0.8, 0.0, 0.6]}]}


@pytest.fixture(scope="module")
def baked(tmp_path_factory, device):
    """The striped floor, the gold sphere and the textured pyramid under a sky with a small bright
    light; its view bake (16 x 16 texels, 16 bits, nearly lossless)."""
    folder = tmp_path_factory.mktemp("relight_view_textured")
    write_lamp_sky(folder)   # a small bright light
    write_glb(folder / "a.glb")
    write_textured_pyramid(folder)
    (folder / "scene.toml").write_text(toml_text(scene_dict()))
    scene = wavlight.load_scene(folder / "scene.toml")
    assert scene.textured
    tr = wavlight.bake(scene, folder / "t.wlt", vary="view", levels=4, density=400, tolerance=1e-3, bits=16)
    return folder, scene, tr


def test_the_cache_points_carry_the_textured_albedo(baked):
    """Each floor point's albedo is the texture's bilinear lookup at its texture coordinates, here
    computed from its place on the floor (the floor's corners carry (0, 0) .. (2, 2)), not from
    the cache's faces; the floor shows both stripes."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    albedo = np.asarray(tr._s["albedo"], np.float64)
    names = [m.name for m in scene.materials]
    floor = frames.material == names.index("a.glb:floor")
    assert floor.sum() > 100
    x, z = frames.position[floor, 0], frames.position[floor, 2]
    uv = np.stack([(x + 2.0) / 4.0 * 2.0, (z + 2.0) / 4.0 * 2.0], 1)   # the floor's uv: (-2, -2) -> (0, 0)
    texels, table = scene.texture_atlas()
    want = textures.lookup(texels, table, np.zeros(floor.sum(), np.int64), uv.astype(np.float32))
    want = want * scene.materials[names.index("a.glb:floor")].albedo
    np.testing.assert_allclose(albedo[floor], want, rtol=2e-4, atol=2e-5)
    ratio = albedo[floor, 1] / albedo[floor, 0]   # red stripes: little green; white ones: as much as red
    assert (ratio < 0.3).sum() > 10 and (ratio > 0.9).sum() > 10, np.percentile(ratio, [5, 50, 95])


def _rays(frames, size=40):
    cam = frames.camera(EYE, TARGET)
    pix = np.arange(size * size)
    o, d = wavlight.camera.camera_rays(dataclasses.replace(frames.scene, camera=cam), pix % size, pix // size,
                                       np.full((len(pix), 2), 0.5, np.float32), size, size)
    prim, t, u, v = frames.tracer.intersect_uv(o, d)
    return d, prim, u, v


def test_assemble_kernel_takes_the_texture_at_the_hit_as_its_twin(baked):
    """view_assemble with -DTEXTURES=1 against the numpy frame's assembly: the blend of the
    points' products times the albedo at the hit, the material's times its texture there
    (ViewFrames.hit_albedo, Scene.albedo_at)."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    d, prim, u, v = _rays(frames)
    fd = view_walk.FrameDevice(frames, view_walk.ViewDevice(tr))
    assert fd.textured
    queue = wavlight.cl.thread_queue()
    ids_b, w_b, prim_b, dir_b, points = fd.lookup(prim, u, v, d, queue)
    rng = np.random.default_rng(5)
    B = np.abs(rng.normal(size=(len(points), 3))).astype(np.float32)
    got = fd.assemble(len(prim), prim_b, ids_b, w_b, dir_b, points, wavlight.cl.to_device(B), queue, uv=(u, v))
    ids = wavlight.cl.read(ids_b, (len(prim), 3), np.uint32, queue).astype(np.int64)
    w = wavlight.cl.read(w_b, (len(prim), 3), np.float32, queue)
    hit = np.flatnonzero(prim >= 0)
    at = np.full(len(frames.position), len(points), np.int64)
    at[points] = np.arange(len(points))
    rows = np.concatenate([B, np.zeros((1, 3), np.float32)])
    tint = frames.hit_albedo(prim[hit], u[hit], v[hit])
    want = np.einsum("ij,ijc->ic", w[hit], rows[at[ids[hit]]]) * tint
    np.testing.assert_allclose(got[hit], want, rtol=1e-5, atol=1e-7)
    plain = scene.material_albedo[scene.face_material[prim[hit]]]
    assert (np.abs(tint - plain).max(1) > 0.1).mean() > 0.2   # the texture shows
    with pytest.raises(ValueError, match="barycentrics"):
        fd.assemble(len(prim), prim_b, ids_b, w_b, dir_b, points, wavlight.cl.to_device(B), queue)


@pytest.mark.parametrize("mode", view_frames.MODES)
def test_the_frames_of_both_backends_agree(baked, mode):
    """The approximate frame on the device and in numpy (the textures read by view_assemble and by
    Scene.albedo_at; in pixel mode on the host by both)."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    a, _ = frames.frame(EYE, TARGET, 32, 32, mode=mode)
    b, _ = frames.frame(EYE, TARGET, 32, 32, mode=mode, backend="numpy")
    close = np.abs(a - b) <= 1e-3 * np.abs(b) + 1e-5
    assert close.mean() > 0.99, close.mean()


@pytest.mark.slow
def test_unbiased_frame_equals_mis_from_another_camera(baked):
    """The unbiased frame (converge_shade with the textures at each camera sample's hit) against
    mis of the textured scene seen from another camera, per 4 x 4 block and channel; the
    approximate frame as near it as without the textures."""
    folder, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    spp = 64
    r = frames.converge(EYE, TARGET, spp=spp, seed=3)
    moved = wavlight.load_dict(scene_dict({"eye": EYE, "target": TARGET, "fov_y": 45.0}), base_dir=folder)
    ref = wavlight.render_full(moved, spp=1024, strategy="mis", seed=11)
    se = np.sqrt(r.stderr.astype(np.float64) ** 2 + ref.stderr.astype(np.float64) ** 2)
    check_estimates(r.image, se, ref.image, np.ones((24, 24), bool), spp, per_pixel=False,
                    label="textured view converge vs mis")
    diff = (r.image.astype(np.float64) - ref.image).reshape(6, 4, 6, 4, 3).sum(axis=(1, 3))
    z = diff / np.sqrt((se ** 2).reshape(6, 4, 6, 4, 3).sum(axis=(1, 3)))
    assert np.abs(z).max() < 4.0, z
    # the approximate frame (4 x 4 rays per pixel, as mis integrates over the pixel) is as near mis
    # on the textured surfaces as that of the same bake without the textures is to mis of the
    # untextured scene (the same random numbers): the texture at the hit adds no error of its own
    plain = dataclasses.replace(scene, materials=[dataclasses.replace(m, texture=-1) for m in scene.materials])
    plain_frames = view_frames.ViewFrames(tr, plain)
    plain_ref = wavlight.render_full(dataclasses.replace(moved, materials=plain.materials), spp=1024, strategy="mis",
                                     seed=11)
    d, prim, _, _ = _rays(frames, 24)
    textured = (prim >= 0) & (scene.material_texture[scene.face_material[np.maximum(prim, 0)]] >= 0)
    textured = textured.reshape(24, 24)
    assert textured.sum() > 200
    for mode in view_frames.MODES:
        errors = []
        for f, want in ((frames, ref), (plain_frames, plain_ref)):
            image, _ = f.frame(EYE, TARGET, mode=mode, supersample=4)
            errors.append(np.linalg.norm((image - want.image)[textured]))
        assert errors[0] < 1.1 * errors[1], (mode, errors)


def test_the_unbiased_frame_of_both_backends_agree(baked):
    """The same unbiased frame (the same random numbers) with the kernels (converge_shade with
    -DTEXTURES=1) and with their numpy twins (the texture at each hit by Scene.albedo_at)."""
    _, scene, tr = baked
    frames = view_frames.ViewFrames(tr, scene)
    a = frames.converge(EYE, TARGET, spp=4, seed=9)
    b = frames.converge(EYE, TARGET, spp=4, seed=9, backend="numpy")
    assert a.stats["backend"] == "opencl" and b.stats["backend"] == "numpy"
    diff = np.abs(a.image - b.image).max(2)
    assert (diff > 1e-3 * (1 + np.abs(b.image).max(2))).mean() < 0.03, diff.max()
    var = (b.stderr ** 2).sum()
    assert abs((a.image - b.image).sum()) < 0.5 * np.sqrt(var)


