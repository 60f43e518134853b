"""Display transforms (wavlight.display): exposure, the tone curves and the sRGB encoding, against
their published definitions; the default transform gives the PNG values wavlight always wrote; the
8-bit encoders (exact for files, a table for the viewer) agree with the float64 reference."""
from __future__ import annotations

import numpy as np
import pytest

from wavlight import display
from wavlight.errors import ArgumentError


def srgb(x):
    """IEC 61966-2-1, written out: 12.92 x below 0.0031308, else 1.055 x^(1/2.4) - 0.055."""
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def narkowicz(x):
    """K. Narkowicz, "ACES Filmic Tone Mapping Curve" (2016): saturate((x*(a*x+b))/(x*(c*x+d)+e))
    with a = 2.51, b = 0.03, c = 2.43, d = 0.59, e = 0.14."""
    x = np.asarray(x, np.float64)
    return np.clip((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)


def test_aces_is_narkowicz_published_fit():
    x = np.concatenate([np.linspace(0.0, 4.0, 401), np.geomspace(4.0, 1e6, 50)])
    np.testing.assert_allclose(display.tone_curve(x, "aces"), narkowicz(x), rtol=1e-12, atol=0)
    # what the source says of it: pre-exposed so that 1 maps to ~0.8; black stays black; it
    # rises monotonically and reaches white (its asymptote 2.51 / 2.43 > 1 is clamped)
    assert display.tone_curve(1.0, "aces") == pytest.approx(0.8, abs=0.01)
    assert display.tone_curve(0.0, "aces") == 0.0
    y = display.tone_curve(np.linspace(0.0, 20.0, 2001), "aces")
    assert np.all(np.diff(y) >= 0) and y[-1] == 1.0
    assert 2.51 / 2.43 > 1.0


def test_curves_of_bad_values_show_black_and_white():
    for curve in display.CURVES:
        out = display.tone_curve(np.array([np.nan, np.inf, -np.inf, -3.0, 1e30], np.float32), curve)
        assert out.tolist() == [0.0, 1.0, 0.0, 0.0, 1.0], curve
    assert display.tone_curve(np.array([0.25, 2.0]), "clamp").tolist() == [0.25, 1.0]


def test_display_is_srgb_of_the_curve_of_the_exposed_value():
    x = np.random.default_rng(3).exponential(0.5, (64, 3))
    for ev in (-2.0, 0.0, 1.25):
        np.testing.assert_allclose(display.display(x, ev, "clamp"), srgb(x * 2.0 ** ev), rtol=0, atol=1e-12)
        np.testing.assert_allclose(display.display(x, ev, "aces"), srgb(narkowicz(x * 2.0 ** ev)), rtol=0,
                                   atol=1e-12)


@pytest.mark.parametrize("curve", display.CURVES)
@pytest.mark.parametrize("ev", [-3.0, 0.0, 0.5, 4.0])
def test_encode8_rounds_the_reference(curve, ev):
    """The files' float32 encoder: the float64 reference x 255, rounded (within one level where
    float32 rounding falls on a half)."""
    x = np.concatenate([np.linspace(-0.5, 3.0, 3000), np.geomspace(1e-6, 1e4, 3000)]).astype(np.float32)
    x = x.reshape(-1, 2, 3)
    want = np.floor(display.display(x.astype(np.float64), ev, curve) * 255 + 0.5)
    got = display.encode8(x, ev, curve)
    assert got.dtype == np.uint8 and got.shape == x.shape
    diff = np.abs(got.astype(int) - want)
    assert diff.max() <= 1 and diff.mean() < 1e-3


def test_default_transform_is_the_clamped_srgb_png_values():
    """Exposure 0 and clamp give exactly srgb(clamp(x)) x 255 + 0.5 truncated, what wavlight's
    PNGs always held (tests/cli/test_cli.py checks the same values through `wavlight render`)."""
    x = np.concatenate([np.linspace(-1, 2, 3999, dtype=np.float32),
                        np.float32([0.0031308, 0.0031307, 0.04045, 1.0, 0.5, 0.0])]).reshape(-1, 1, 3)
    want = (display.srgb_encode(x) * 255.0 + 0.5).astype(np.uint8)
    np.testing.assert_array_equal(display.encode8(x), want)
    np.testing.assert_array_equal(display.encode8(x, 0.0, "clamp"), want)
    assert display.is_identity() and display.is_identity(0, "clamp")
    assert not display.is_identity(0.5) and not display.is_identity(0.0, "aces")


@pytest.mark.parametrize("curve", display.CURVES)
def test_the_viewers_table_is_within_one_level_of_the_files(curve):
    x = np.random.default_rng(4).exponential(0.6, (31, 17, 3)).astype(np.float32)
    for ev in (-1.0, 0.0, 1.5):
        a = display.encode8_lut(x, ev, curve).astype(int)
        assert np.abs(a - display.encode8(x, ev, curve)).max() <= 1
    rgba = display.encode8_lut(x, 0.0, curve, alpha=True)
    assert rgba.shape == (31, 17, 4) and (rgba[..., 3] == 255).all()


def test_settings_are_checked_by_their_records():
    assert display.check(1.5, "aces") == (1.5, "aces")
    for bad in ({"exposure": float("nan")}, {"exposure": 99.0}, {"exposure": "1"}, {"tonemap": "agx"}):
        with pytest.raises(ArgumentError) as e:
            display.check(**bad)
        assert "\n" not in str(e.value)
    assert display.TONEMAP.default == "clamp" and display.EXPOSURE.default == 0.0
