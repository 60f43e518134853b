"""wavlight.imageio.save_image and negative pixels (the wavelet control variate's shadowed
pixels can average below 0): kept by .exr and .pfm, 0 in .hdr (RGBE has no sign: OIIO
would write -0.5 as 1.5) and in .png."""
import numpy as np
import OpenImageIO as oiio
import pytest

from wavlight.imageio import save_image

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
