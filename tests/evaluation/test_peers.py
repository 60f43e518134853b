"""Mitsuba 3 as a peer (optional: skipped when Mitsuba or its LLVM backend is missing)."""
import numpy as np
import pytest

import wavlight
from wavlight.evaluation import peers
from wavlight.envmap import Environment

pytestmark = pytest.mark.skipif(not peers.available(), reason="Mitsuba 3 (llvm_ad_rgb) not available")


def test_envmap_lookup_matches_inside_texels():
    """Upsampled k times, Mitsuba's bilinear lookup equals the nearest texel except in the blend
    band of half a fine texel on each side of every original texel edge: a fraction
    1 - (1 - 1/k)^2 of the square (by area in (u, v); directions are uniform in solid angle,
    so allow 50% slack) -- and a wrong orientation or rotation would mismatch almost everywhere."""
    rng = np.random.default_rng(4)
    env = Environment(rng.random((16, 32, 3)).astype(np.float32) + 0.1, 1.0, 30.0)
    for k in (4, 16):
        band = 1 - (1 - 1 / k) ** 2
        assert peers.envmap_mismatch(env, upsample=k, count=50_000) < 1.5 * band


@pytest.mark.parametrize("strategy", ["mis", "mis_comp"])
def test_furnace_agrees_with_wavlight(tmp_path, strategy):
    """Constant environment, lambert sphere: both renderers give the albedo on the sphere."""
    wavlight.save_image(str(tmp_path / "white.exr"), np.ones((8, 16, 3), np.float32))
    scene = wavlight.load_dict({
        "render": {"width": 16, "height": 16, "spp": 8},
        "camera": {"eye": [0.0, 0.0, 4.0], "target": [0.0, 0.0, 0.0], "fov_y": 20.0},
        "environment": {"file": "white.exr"},
        "objects": [{"shape": "sphere", "center": [0.0, 0.0, 0.0], "radius": 1.0, "material": "m"}],
        "materials": {"m": {"type": "lambert", "albedo": [0.5, 0.5, 0.5]}}}, base_dir=tmp_path)
    r = peers.render_mitsuba(scene, strategy, spp=256)
    centre = r.image[6:10, 6:10]
    # Mitsuba reports no per-pixel error; its per-pixel spread estimates the standard error of the mean
    se = centre.std() / np.sqrt(centre.size)
    assert abs(centre.mean() - 0.5) < 5 * se + 1e-3


@pytest.mark.slow
def test_textured_glb_agrees_with_mitsuba(tmp_path):
    """The GLB of tests/support/assets_util (a gold metal sphere, a metal floor with its sRGB
    stripes texture; flat faces: both renderers take face normals) under the indoor map: wavlight's
    mis and Mitsuba's (roughconductor, material none, the texture as a bilinear repeating bitmap
    read through Mitsuba's own OBJ texture coordinates) agree over the floor's and the sphere's
    pixels within 1.5% plus four of the difference's standard errors (Mitsuba's from the spread of
    four independent renders per pixel)."""
    from assets_util import write_glb
    from scenes_util import camera_of
    from wavlight.raytrace import RayTracer

    w, h = 64, 48
    scene = wavlight.load_asset(write_glb(tmp_path / "a.glb"), "data:st_fagans_interior_512", w, h)
    ours = wavlight.render_full(scene, spp=256, strategy="mis", seed=3)
    theirs = np.stack([peers.render_mitsuba(scene, "mis", spp=64, seed=s).image for s in range(4)])
    mean, se_m = theirs.mean(0), theirs.std(0, ddof=1) / 2
    cam = camera_of(scene)
    d = cam.centre_rays().reshape(-1, 3)
    prim, _ = RayTracer(scene.vertices, scene.faces).intersect(np.broadcast_to(cam.eye, d.shape), d)
    which = np.where(prim >= 0, scene.face_material[np.maximum(prim, 0)], -1).reshape(h, w)
    for k, material in enumerate(scene.materials):
        mask = which == k
        assert mask.sum() > 30, material.name
        a, b = ours.image[mask].mean(0), mean[mask].mean(0)
        se = np.sqrt((ours.stderr[mask] ** 2).sum(0) + (se_m[mask] ** 2).sum(0)) / mask.sum()
        assert np.all(np.abs(a - b) <= 0.015 * b + 4 * se), (material.name, a, b, se)
