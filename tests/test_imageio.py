"""wavlight.imageio.save_image and negative pixels (the wavelet control variate's shadowed
pixels can average below 0): kept by .exr and .pfm, 0 in .hdr (RGBE has no sign: OIIO
would write -0.5 as 1.5) and in .png; a PNG's display transform (exposure, tone curve) and
linear outputs left untouched; metadata written and read back."""
import numpy as np
import OpenImageIO as oiio
import pytest

import wavlight
from wavlight.errors import ArgumentError
from wavlight.imageio import LINEAR, PROVENANCE_KEYS, provenance, read_metadata, save_image, save_images

IMAGE = np.array([[[-0.5, 0.25, 1.0], [0.375, -1e-3, 2.0]]], np.float32)


def _read(path):
    inp = oiio.ImageInput.open(str(path))
    try:
        return inp.read_image(format=oiio.FLOAT)
    finally:
        inp.close()


@pytest.mark.parametrize("ext", [".exr", ".pfm"])
def test_float_formats_keep_negative_pixels(tmp_path, ext):
    save_image(tmp_path / f"x{ext}", IMAGE)
    np.testing.assert_array_equal(_read(tmp_path / f"x{ext}").reshape(IMAGE.shape), IMAGE)


def test_hdr_writes_negative_pixels_as_zero(tmp_path):
    save_image(tmp_path / "x.hdr", IMAGE)
    got = _read(tmp_path / "x.hdr").reshape(IMAGE.shape)
    want = np.maximum(IMAGE, 0)
    assert np.all(got[want == 0] == 0)
    np.testing.assert_allclose(got, want, rtol=2 ** -7)   # RGBE: 8-bit mantissas


def test_png_clamps_negative_pixels(tmp_path):
    save_image(tmp_path / "x.png", IMAGE)
    got = _read(tmp_path / "x.png").reshape(IMAGE.shape)
    assert got[0, 0, 0] == 0 and got[0, 1, 1] == 0 and got[0, 1, 2] == 1


def test_save_images_is_all_or_nothing(tmp_path):
    """save_images writes every (path, image) pair or none: a pair that fails (here a NaN
    pixel, or an unknown format) leaves the other targets and no temporary file behind."""
    from wavlight.errors import WavlightError
    from wavlight.imageio import save_images

    bad = IMAGE.copy()
    bad[0, 0, 0] = np.nan
    for second, message in (((tmp_path / "b.exr", bad), "NaN"), ((tmp_path / "b.tif", IMAGE), "format")):
        with pytest.raises(WavlightError, match=message):
            save_images([(tmp_path / "a.exr", IMAGE), second])
        assert list(tmp_path.iterdir()) == []
    save_images([(tmp_path / "a.exr", IMAGE), (tmp_path / "b.pfm", IMAGE)])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr", "b.pfm"]


def test_a_write_error_reported_only_as_text_fails(tmp_path, monkeypatch):
    """OpenImageIO's PNG writer on a full disk returns True from write_image and close and
    reports the failed writes only through geterror() (seen on a 16 KiB tmpfs: a truncated
    file, exit 0): that text alone makes the write fail, and no file is left."""
    from wavlight.errors import WavlightError

    real_create = oiio.ImageOutput.create

    class FullDisk:
        def __init__(self, inner):
            self.inner = inner

        def open(self, *a):
            return self.inner.open(*a)

        def write_image(self, *a):
            return self.inner.write_image(*a)

        def geterror(self):
            return "Write error at position 16569, could only write 3911/8192 bytes"

        def close(self):
            return self.inner.close()

    monkeypatch.setattr(oiio.ImageOutput, "create", lambda path: FullDisk(real_create(path)))
    with pytest.raises(WavlightError, match="x.png: write failed .*could only write"):
        save_image(tmp_path / "x.png", IMAGE)
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- display transforms
def _narkowicz_srgb8(x):
    """srgb(clamp(x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14))) x 255, rounded: Narkowicz's
    published ACES fit and IEC 61966-2-1, written out."""
    x = np.maximum(np.asarray(x, np.float64), 0.0)
    y = np.clip(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)
    s = np.where(y <= 0.0031308, 12.92 * y, 1.055 * y ** (1 / 2.4) - 0.055)
    return np.floor(s * 255 + 0.5)


def test_png_takes_the_exposure_and_the_tone_curve(tmp_path):
    image = np.random.default_rng(5).exponential(1.0, (9, 14, 3)).astype(np.float32)
    save_image(tmp_path / "x.png", image, exposure=-1.5, tonemap="aces")
    got = _read(tmp_path / "x.png").reshape(image.shape) * 255
    assert np.abs(got - _narkowicz_srgb8(image.astype(np.float64) * 2 ** -1.5)).max() <= 1


def test_default_png_has_no_metadata_and_the_same_pixels(tmp_path):
    """Without metadata and with the default transform a PNG is what it always was: no text
    chunks, the clamped sRGB values."""
    from PIL import Image

    save_image(tmp_path / "a.png", IMAGE)
    save_image(tmp_path / "b.png", IMAGE, exposure=0.0, tonemap="clamp")
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    with Image.open(tmp_path / "a.png") as im:
        assert im.text == {}
    assert read_metadata(tmp_path / "a.png") == {}


@pytest.mark.parametrize("ext", LINEAR)
def test_linear_outputs_refuse_a_display_transform(tmp_path, ext):
    """A linear file holds the radiance: an exposure or a curve for it is one line, nothing is
    written; the identity is accepted and the file's pixels are the image's."""
    for bad in ({"exposure": 1.0}, {"tonemap": "aces"}, {"exposure": -2.0, "tonemap": "aces"}):
        with pytest.raises(ArgumentError) as e:
            save_image(tmp_path / f"x{ext}", IMAGE, **bad)
        assert "\n" not in str(e.value) and "linear" in str(e.value)
        assert list(tmp_path.iterdir()) == []
    save_image(tmp_path / f"x{ext}", IMAGE, exposure=0.0, tonemap="clamp")
    if ext != ".hdr":
        np.testing.assert_array_equal(_read(tmp_path / f"x{ext}").reshape(IMAGE.shape), IMAGE)


def test_save_images_transforms_the_png_and_keeps_the_exr_linear(tmp_path):
    save_images([(tmp_path / "x.png", IMAGE), (tmp_path / "x.exr", IMAGE)], exposure=2.0, tonemap="aces")
    np.testing.assert_array_equal(_read(tmp_path / "x.exr").reshape(IMAGE.shape), IMAGE)
    got = _read(tmp_path / "x.png").reshape(IMAGE.shape) * 255
    assert np.abs(got - _narkowicz_srgb8(IMAGE.astype(np.float64) * 4.0)).max() <= 1


# ----------------------------------------------------------------------------- metadata
@pytest.mark.parametrize("ext", [".exr", ".png"])
def test_metadata_reads_back(tmp_path, ext):
    meta = provenance("wavelet", 64, 2 ** 62 + 7, "ab" * 32, note="x y")
    assert list(meta)[:5] == list(PROVENANCE_KEYS)
    save_image(tmp_path / f"x{ext}", IMAGE, metadata=meta)
    got = read_metadata(tmp_path / f"x{ext}")
    assert {k: got[k] for k in meta} == {k: str(v) for k, v in meta.items()}
    assert got["version"] == wavlight.__version__
    if ext == ".png":   # tEXt chunks, read by another reader too; and how the PNG shows the image
        from PIL import Image

        with Image.open(tmp_path / "x.png") as im:
            assert im.text["wavlight:seed"] == str(2 ** 62 + 7) and im.text["wavlight:strategy"] == "wavelet"
        assert (got["exposure"], got["tonemap"]) == ("0.0", "clamp")
    else:
        assert "exposure" not in got


def test_formats_without_a_header_for_it_write_no_metadata(tmp_path):
    for ext in (".hdr", ".pfm"):
        save_image(tmp_path / f"x{ext}", IMAGE, metadata=provenance("mis", 4, 0, "00"))
        assert (tmp_path / f"x{ext}").exists()
    assert read_metadata(tmp_path / "x.hdr") == {}


@pytest.mark.parametrize("bad", [["spp", 4], {"": 1}, {"a b": 1}, {"é": 1}, {"x": None}, {"x": float("nan")},
                                 {"x": [1]}, {"x": "y" * 3000}, {"x": "a\0b"}])
def test_bad_metadata_is_one_line(tmp_path, bad):
    with pytest.raises(ArgumentError) as e:
        save_image(tmp_path / "x.exr", IMAGE, metadata=bad)
    assert "\n" not in str(e.value) and list(tmp_path.iterdir()) == []
