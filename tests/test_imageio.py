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
