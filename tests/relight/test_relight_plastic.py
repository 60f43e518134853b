"""Plastic (Mitsuba 3's roughplastic) in the lighting bake: its coat, which the albedo does not
multiply, is a second transfer stored for the blocks that see plastic (wavlight/relight/store.py
COAT_SECTIONS); frames add it (kernel frame_product with COAT, twin frame.coat_reference), the
bake's texel kernel estimates it (part 1, twin texel_rays_reference) and the unbiased frame
shades plastic exactly (docs/decisions/plastic-in-the-bake.md)."""
from __future__ import annotations

import os

import numpy as np
import pytest

import wavlight
from wavlight.raytrace import RayTracer
from wavlight.relight import bake as bake_mod
from wavlight.relight import frame as frame_mod
from wavlight.relight import lighting
from wavlight.relight.converge import COHERENCE, converge
from scenes_util import over_floor, write_raw_image

PLASTIC = {"type": "plastic", "albedo": [0.7, 0.3, 0.1], "alpha": 0.2}


def plastic_scene(env, width=24, height=24, floor="lambert"):
    """A plastic sphere over a floor (lambert, or plastic too) under ``env``."""
    floor_m = ({"type": "lambert", "albedo": [0.6, 0.6, 0.6]} if floor == "lambert"
               else {"type": "plastic", "albedo": [0.2, 0.4, 0.6], "alpha": 0.4, "ior": 1.3})
    return {"render": {"width": width, "height": height},
            "camera": {"eye": [0.0, 1.5, 3.5], "target": [0.0, 0.5, 0.0], "fov_y": 40.0},
            "environment": env,
            "objects": [{"shape": "sphere", "center": [0.0, 0.6, 0.0], "radius": 0.6, "subdivisions": 3,
                         "material": "ball"},
                        {"shape": "quad", "center": [0.0, 0.0, 0.0], "size": 6.0, "material": "floor"}],
            "materials": {"ball": PLASTIC, "floor": floor_m}}


@pytest.fixture(scope="module")
def maps(tmp_path_factory):
    folder = tmp_path_factory.mktemp("plastic_maps")
    rng = np.random.default_rng(5)
    sky = (np.linspace(2.0, 0.2, 32)[:, None, None] * np.ones((32, 64, 3))
           * rng.uniform(0.7, 1.3, (32, 64, 3))).astype(np.float32)
    sky[5:8, 38:42] = 30.0                                 # a bright patch: a highlight on the coat
    write_raw_image(folder / "sky.exr", sky)
    other = (np.linspace(0.3, 1.5, 32)[:, None, None] * np.ones((32, 64, 3))
             * np.array([1.0, 0.8, 0.6])).astype(np.float32)
    other[10:13, 5:9] = 20.0
    write_raw_image(folder / "other.exr", other)
    return folder


@pytest.fixture(scope="module")
def baked(maps, device):
    scene = wavlight.load_dict(plastic_scene({"file": "sky.exr", "rotate_y": 20.0}, floor="plastic"), base_dir=maps)
    transfer = wavlight.bake(scene, spp=4, levels=4, terms=256, priority="area", tolerance=1e-4, bits=16)
    return scene, transfer


def test_coat_texel_rays_kernel_equals_its_twin(baked):
    scene, _ = baked
    tracer = RayTracer(scene.vertices, scene.faces, normals=scene.normals, normal_faces=scene.normal_faces)
    ps = bake_mod.camera_samples(scene, tracer, 24, 24, 0, 8, 16, 8, 4, 5, 3)
    assert ps.has_coat
    for part in (0, 1):   # the albedo's part (plastic's base), the coat's
        d, w, pick = bake_mod.texel_rays(ps, 4, 5, 3, points=4, part=part)
        d2, w2, pick2 = bake_mod.texel_rays_reference(ps, 4, 5, 3, points=4, part=part)
        assert w2.max() > 0
        np.testing.assert_allclose(w, w2, rtol=2e-3, atol=1e-6 * w2.max())
        live = w2 > 0
        agree = (pick == pick2) & (np.abs(d - d2).max(1) < 1e-4)
        assert agree[live].mean() > 0.995


def test_coat_frame_kernel_equals_its_twin(baked):
    _, tr = baked
    s = tr._s
    assert tr.header["coat"] and 0 < len(s["coat_blocks"]) <= tr.blocks[0] * tr.blocks[1]
    coeffs = tr.lighting(rotate_y=50.0)
    cols = lighting.select_terms(coeffs, 64, "area")
    values = coeffs.reshape(3, -1)[:, cols].T * 256.0
    device = frame_mod.DeviceFrame(s, tr.width, tr.height, tr.blocks[0], tr.spp)
    kernel = device.read(device.product(cols, values))
    twin = frame_mod.image_reference(s["offsets"], s["entry_scale"], s["entry_data"], cols, values, s["albedo"],
                                     tr.blocks[0])
    coat = frame_mod.coat_reference(s["coat_blocks"], s["coat_offsets"], s["coat_entry_scale"], s["coat_entry_data"],
                                    cols, values, tr.blocks[0] * tr.blocks[1], tr.blocks[0], tr.width, tr.height)
    assert np.abs(coat).max() > 0
    np.testing.assert_allclose(kernel, twin + coat, rtol=1e-5, atol=1e-6 * np.abs(twin + coat).max())
    a = tr.frame(rotate_y=50.0, terms=64, priority="area")
    b = tr.frame(rotate_y=50.0, terms=64, priority="area", backend="numpy")
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5 * b.max())


def test_sparse_product_with_the_coat_equals_the_dense_dot_product(baked):
    """With every term and (nearly) no compression, a frame is a_p sum_t T_p,t L_t + sum_t C_p,t L_t
    of the bake's texel transfer T and coat C, which the twin of the bake computes densely."""
    scene, tr = baked
    tracer = RayTracer(scene.vertices, scene.faces, normals=scene.normals, normal_faces=scene.normal_faces)
    env = scene.environment
    L = lighting.project(env, 4, 75.0)
    image = np.zeros((24, 24, 3))
    for tile in bake_mod._tiles(24, 24)[0]:   # the blocks of the image
        block, x0, y0, w, h = tile
        ps = bake_mod.camera_samples(scene, tracer, 24, 24, x0, y0, w, h, tr.spp, tr.header["seed"], block)
        T, _ = bake_mod.tile_transfer(ps, tracer, 4, tr.header["seed"], block, points=tr.header["texel_points"])
        C, _ = bake_mod.tile_transfer(ps, tracer, 4, tr.header["seed"], block, points=tr.header["texel_points"],
                                      part=1)
        image[y0:y0 + h, x0:x0 + w] = (np.einsum("pij,ijc->pc", T, L) * ps.albedo
                                       + np.einsum("pij,ijc->pc", C, L)).reshape(h, w, 3)
    hits = np.asarray(tr._s["albedo"]).sum(-1) > 0
    got = tr.frame(rotate_y=75.0)
    background = np.zeros_like(got)
    bp = np.asarray(tr._s["background_pixel"], np.int64)
    background.reshape(-1, 3)[bp] = frame_mod.background_reference(
        env.pixels, 75.0, tr._s["background_mask"], *frame_mod.background_lookup(tr._s["background_dir"], env.height))
    np.testing.assert_allclose((got - background)[hits], image[hits], rtol=2e-3, atol=1e-4 * image.max())


def test_only_blocks_that_see_plastic_store_a_coat(maps, device):
    """A plastic sphere seen in the image's top-left block alone: one coat block; a scene without
    plastic has no coat sections at all."""
    d = plastic_scene({"file": "sky.exr"}, width=48, height=32)
    d["camera"] = {"eye": [2.4, 1.2, 3.0], "target": [0.0, 0.4, 0.0], "fov_y": 30.0}
    kw = dict(spp=2, levels=3, terms=32, priority="area", tolerance=1e-3, bits=8)
    tr = wavlight.bake(wavlight.load_dict(d, base_dir=maps), **kw)
    seen = np.unique((np.argwhere(np.asarray(tr._s["albedo"])[..., 0] > 0.65) // 16) @ [tr.blocks[0], 1])
    assert set(tr._s["coat_blocks"].tolist()) <= set(range(tr.blocks[0] * tr.blocks[1]))
    assert 0 < len(tr._s["coat_blocks"]) < tr.blocks[0] * tr.blocks[1], tr._s["coat_blocks"]
    assert set(seen.tolist()) <= set(tr._s["coat_blocks"].tolist())
    d["materials"]["ball"] = {"type": "ggx", "albedo": [0.7, 0.3, 0.1], "roughness": 0.3}
    plain = wavlight.bake(wavlight.load_dict(d, base_dir=maps), **kw)
    assert "coat" not in plain.header and "coat_blocks" not in plain._s


def corrected_error(image, ref, mask) -> float:
    """The relative L2 error of ``image`` against the truth, from a reference render ``ref`` (a
    RenderResult) of it: ||image - ref||^2 less the reference's own noise sum(stderr^2), over
    ||ref||^2 (their difference is the error plus the reference's independent noise)."""
    diff = (image - ref.image)[mask].astype(np.float64)
    noise = (ref.stderr[mask].astype(np.float64) ** 2).sum()
    return float(np.sqrt(max((diff ** 2).sum() - noise, 0.0) / (ref.image[mask].astype(np.float64) ** 2).sum()))


@pytest.mark.slow
@pytest.mark.parametrize("ball", ["plastic", "ggx"])
def test_plastic_frames_agree_with_mis(maps, device, ball):
    """The relit frame of a plastic scene (a plastic sphere on a plastic floor) under the baked map,
    that map turned 110 degrees and another map agrees with ``wavlight render --strategy mis`` of
    the same changed scene within the bake's own predicted error (its pilots' measure of noise,
    texels and terms, with the compression's share; the map's turns are what the pilots measure,
    another map gets twice that), mis's own noise taken out; as a ggx ball on a lambert floor does."""
    d = plastic_scene({"file": "sky.exr"}, floor="plastic" if ball == "plastic" else "lambert")
    if ball == "ggx":
        d["materials"]["ball"] = {"type": "ggx", "albedo": [0.7, 0.3, 0.1], "roughness": 0.3}
    scene = wavlight.load_dict(d, base_dir=maps)
    tr = wavlight.bake(scene, tolerance=0.03, seed=2)
    predicted = tr.measured["predicted_error"]
    assert predicted is not None and tr.header.get("coat", False) == (ball == "plastic")
    hits = np.asarray(tr._s["albedo"]).sum(-1) > 0
    for env, rot, allowed in ((None, 0.0, 1.5), (None, 110.0, 1.5), ("other.exr", 30.0, 3.0)):
        changed = dict(d, environment={"file": env or "sky.exr", "rotate_y": rot})
        ref = wavlight.render_full(wavlight.load_dict(changed, base_dir=maps), spp=1024, strategy="mis", seed=7)
        got = tr.frame(env=None if env is None else os.path.join(maps, env), rotate_y=rot)
        err = corrected_error(got, ref, hits)
        assert err < allowed * predicted, (ball, env, rot, err, predicted)


@pytest.fixture(scope="module")
def turned_mis(baked, maps):
    scene, _ = baked
    d = plastic_scene({"file": "sky.exr", "rotate_y": 80.0}, floor="plastic")
    return wavlight.render_full(wavlight.load_dict(d, base_dir=maps), spp=512, strategy="mis", seed=11)


@pytest.mark.parametrize("control, coherence", [(True, COHERENCE), (False, COHERENCE), (True, 0.0)])
def test_unbiased_plastic_frame_equals_mis(baked, turned_mis, control, coherence):
    """The unbiased frame of the plastic scene (its product trees with the coat, plastic shaded
    exactly) against mis of the same scene under the turned map, within their standard errors:
    with the relit frame as control variate and without, and with every sample resampled."""
    scene, tr = baked
    r = converge(tr, scene, rotate_y=80.0, spp=64, seed=3, control=control, coherence=coherence)
    ref = turned_mis
    var = r.stderr.astype(np.float64) ** 2 + ref.stderr.astype(np.float64) ** 2
    # 4 x 4 blocks of pixels of the 24 x 24 image, per channel: 108 z values, Sidak-corrected 1%
    diff = (r.image - ref.image).reshape(6, 4, 6, 4, 3).sum(axis=(1, 3))
    z = diff / np.sqrt(var.reshape(6, 4, 6, 4, 3).sum(axis=(1, 3)))
    assert np.abs(z).max() < 4.0, z
    total = (r.image - ref.image).sum() / np.sqrt(var.sum())
    assert abs(total) < 3.3, total


def moving_scene(translate):
    """A plastic ball (the object that moves) over a plastic floor under write_sun_sky's sun."""
    d = over_floor({"shape": "sphere", "name": "ball", "translate": list(translate), "radius": 0.5,
                    "subdivisions": 3}, width=32, height=24, target=(0.0, 0.3, 0.0))
    d["materials"]["m"] = PLASTIC
    d["materials"]["floor"] = {"type": "plastic", "albedo": [0.2, 0.4, 0.6], "alpha": 0.4, "ior": 1.3}
    return d


@pytest.mark.slow
def test_object_bake_of_plastic_is_unbiased_against_mis(tmp_path, device):
    """An object bake of a plastic ball over a plastic floor (its product leaves with the coat, the
    occlusion shaded exactly): frames at two places agree with mis of the moved scene."""
    from scenes_util import write_sun_sky
    from wavlight.relight.moving import MovingObject

    write_sun_sky(tmp_path)
    scene = wavlight.load_dict(moving_scene((0.0, 0.5, 0.0)), base_dir=tmp_path)
    tr = wavlight.bake(scene, spp=4, levels=5, terms=256, priority="area", vary="object", object="ball",
                       static_spp=256)
    for translate in ((0.0, 0.5, 0.0), (0.9, 0.5, -0.5)):
        r = MovingObject(tr, scene).frame(translate=translate, spp=32, seed=4)
        ref = wavlight.render_full(wavlight.load_dict(moving_scene(translate), base_dir=tmp_path), spp=1024,
                                   strategy="mis", seed=9)
        var = r.stderr.astype(np.float64) ** 2 + ref.stderr.astype(np.float64) ** 2
        z_total = (r.image - ref.image).sum() / np.sqrt(var.sum())
        blocks = lambda a: a.reshape(4, 6, 4, 8, 3).sum(axis=(1, 3))   # noqa: E731  (48 sums of 48 pixels)
        z = blocks(r.image - ref.image) / np.sqrt(blocks(var))
        assert abs(z_total) < 3.3 and np.abs(z).max() < 3.9, (translate, z_total, np.abs(z).max())
        assert r.stats["object_pixels"] > 0
