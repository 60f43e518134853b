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
