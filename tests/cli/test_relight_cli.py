"""`wavlight bake` and `wavlight frame`: outputs, --json, turntables, the unbiased frame, bad input
(one line, exit 2, nothing written) and a bake on a Dask cluster identical to a local one."""
from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest
from click.testing import CliRunner

from scenes_util import toml_text, write_raw_image
from wavlight import animation
from wavlight.cli.main import main
from wavlight.relight import store

SCENE = {"render": {"width": 16, "height": 12},
         "camera": {"eye": [0.0, 1.2, 3.0], "target": [0.0, 0.4, 0.0], "fov_y": 40.0},
         "environment": {"file": "sky.exr", "rotate_y": 30.0},
         "objects": [{"shape": "sphere", "center": [0.0, 0.5, 0.0], "radius": 0.5, "subdivisions": 2,
                      "material": "m"},
                     {"shape": "quad", "size": 4.0}],
         "materials": {"m": {"type": "ggx", "albedo": [0.9, 0.8, 0.7], "roughness": 0.3}}}
FAST = ["--spp", "2", "--levels", "3", "--terms", "32", "--priority", "area"]


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def animations(stem):
    """The animations a turntable or an orbit writes here: the APNG, and the MP4 with PyAV."""
    return sorted(os.path.basename(p) for k, p in animation.paths("", stem).items()
                  if k == "apng" or animation.has_mp4())


def one_error_line(r, *words):
    assert r.exit_code == 2, r.output
    lines = [line for line in r.stderr.splitlines() if line.strip() and not line.startswith("warning:")]
    assert len(lines) == 1 and lines[0].startswith("Error: "), r.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])
    assert "Traceback" not in r.output


@pytest.fixture(scope="module")
def baked(tmp_path_factory, device):
    folder = tmp_path_factory.mktemp("relight_cli")
    rng = np.random.default_rng(0)
    write_raw_image(folder / "sky.exr", rng.uniform(0.2, 2.0, (16, 32, 3)).astype(np.float32))
    write_raw_image(folder / "black.exr", np.zeros((8, 16, 3), np.float32))
    (folder / "scene.toml").write_text(toml_text(SCENE))
    out = folder / "scene.wlt"
    r = run("bake", folder / "scene.toml", "-o", out, *FAST, "--json")
    assert r.exit_code == 0, r.output
    return folder, out, json.loads(r.stdout)


def test_bake_json(baked):
    _, out, stats = baked
    assert os.path.getsize(out) == stats["file_bytes"] > 0
    for key in ("bake_seconds", "rays_per_second", "texels", "terms", "priority", "spp", "measured",
                "file_bytes", "entries"):
        assert key in stats, key
    assert stats["texels"] == "8x8" and stats["terms"] == 32 and stats["rays"] > 0
    assert [f for f in os.listdir(out.parent) if f.startswith(".wavlight-")] == []


def test_frame_json_turntable_and_spp(baked, tmp_path):
    folder, out, _ = baked
    r = run("frame", out, "-o", tmp_path / "f.png", "--rotate-y", "90", "--terms", "16", "--json")
    assert r.exit_code == 0, r.output
    stats = json.loads(r.stdout)
    assert stats["frame_seconds"] > 0 and stats["frames_per_second"] > 0 and stats["terms"] == 16
    assert (tmp_path / "f.png").stat().st_size > 0
    r = run("frame", out, "--turntable", 3, "-o", tmp_path / "turn", "--quiet")
    assert r.exit_code == 0, r.output
    assert sorted(os.listdir(tmp_path / "turn")) == ["frame-0000.png", "frame-0001.png", "frame-0002.png",
                                                     *animations("turntable")]
    r = run("frame", out, "--spp", 2, "-o", tmp_path / "c.exr", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["spp"] == 2 and (tmp_path / "c.exr").exists()


def test_frame_background(baked, tmp_path):
    """--background: the relit and the unbiased frames report it; the bilinear sky differs from the
    nearest one's; a value that is not one of them is refused by click (exit 2, no traceback)."""
    from wavlight.envmap import read_image

    folder, out, _ = baked
    images = {}
    for background in ("nearest", "bilinear", "none"):
        name = tmp_path / f"{background}.exr"
        r = run("frame", out, "-o", name, "--background", background, "--repeat", 1, "--json")
        assert r.exit_code == 0, r.output
        assert json.loads(r.stdout)["background"] == background
        images[background] = read_image(str(name))
        r = run("frame", out, "--spp", 2, "-o", tmp_path / f"u-{background}.exr", "--background", background,
                "--json")
        assert r.exit_code == 0, r.output
        assert json.loads(r.stdout)["background"] == background
    assert not np.array_equal(images["nearest"], images["bilinear"])
    # none: the relit product alone (the map adds nothing where samples missed)
    assert (images["none"] <= images["nearest"]).all() and not np.array_equal(images["none"], images["nearest"])
    assert json.loads(run("frame", out, "-o", tmp_path / "d.png", "--repeat", 1, "--json").stdout)["background"] \
        == "nearest"
    r = run("frame", out, "-o", tmp_path / "c.png", "--background", "cubic")
    assert r.exit_code == 2 and "Traceback" not in r.output and not (tmp_path / "c.png").exists()


@pytest.mark.parametrize("args, words", [
    (("--terms", 0), ("--terms",)),
    (("--rotate-y", "nan"), ("--rotate-y", "finite")),
    (("--rotate-y", "inf"), ("--rotate-y",)),
    (("--scale", "-1"), ("--scale",)),
    (("--scale", "nan"), ("--scale", "finite")),   # click's range lets NaN through: the flag's own line
    (("--env", "black.exr"), ("black.exr", "black everywhere")),
    (("--env", "missing.exr"), ("missing.exr",)),
    (("-o", "x.tiff"), ("x.tiff", "unsupported output format")),
])
def test_frame_bad_input(baked, tmp_path, args, words):
    folder, out, _ = baked
    args = [os.path.join(folder, a) if str(a).endswith(".exr") and a != "x.tiff" else a for a in args]
    if "-o" not in args:
        args += ["-o", tmp_path / "f.png"]
    one_error_line(run("frame", out, *args), *words)
    assert not (tmp_path / "f.png").exists()


def test_damaged_bake_files(baked, tmp_path):
    _, out, _ = baked
    raw = out.read_bytes()
    cases = {"short.wlt": raw[:-64], "junk.wlt": b"#?RADIANCE\n" * 20}
    header = store.read_header(str(out))
    at = header["data_offset"] + header["sections"]["entry_scale"]["offset"]
    damaged = bytearray(raw)
    damaged[at] ^= 0xFF
    cases["bad.wlt"] = bytes(damaged)
    words = {"short.wlt": "truncated", "junk.wlt": "not a wavlight bake file", "bad.wlt": "damaged"}
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        one_error_line(run("frame", tmp_path / name, "-o", tmp_path / "f.png"), name, words[name])
    one_error_line(run("frame", tmp_path / "none.wlt", "-o", tmp_path / "f.png"), "none.wlt")
    assert not (tmp_path / "f.png").exists()


def test_outputs_that_name_inputs_are_refused(baked, tmp_path):
    folder, out, _ = baked
    before = out.read_bytes()
    one_error_line(run("bake", folder / "scene.toml", "-o", folder / "sky.exr", *FAST), "input of this run")
    one_error_line(run("bake", folder / "scene.toml", "-o", folder / "scene.toml", *FAST), "input of this run")
    env = folder / "sky.exr"
    one_error_line(run("frame", out, "--env", env, "-o", env), "input of this run")
    assert out.read_bytes() == before


def test_bake_bad_input(baked, tmp_path):
    folder, _, _ = baked
    one_error_line(run("bake", folder / "nope.toml", "-o", tmp_path / "x.wlt"), "nope.toml")
    (tmp_path / "black.toml").write_text(toml_text({**SCENE, "environment": {"file": str(folder / "black.exr")}}))
    one_error_line(run("bake", tmp_path / "black.toml", "-o", tmp_path / "x.wlt", *FAST), "black everywhere")
    one_error_line(run("bake", folder / "scene.toml", "-o", tmp_path / "nowhere" / "x.wlt"), "no folder")
    r = run("bake", folder / "scene.toml", "-o", tmp_path / "x.wlt", "--spp", 0)
    assert r.exit_code == 2
    assert not (tmp_path / "x.wlt").exists()


def test_dask_bake_equals_local(baked, tmp_path):
    distributed = pytest.importorskip("distributed")
    folder, out, _ = baked
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as c:
        r = run("bake", folder / "scene.toml", "-o", tmp_path / "d.wlt", *FAST, "--dask", c.scheduler_address)
        assert r.exit_code == 0, r.output
    a, b = store.read_header(str(out)), store.read_header(str(tmp_path / "d.wlt"))
    assert {k: v["crc32"] for k, v in a["sections"].items()} == {k: v["crc32"] for k, v in b["sections"].items()}
    assert not math.isnan(b["measured"]["compression_error"])


# ----------------------------------------------------------------------------- looks and outputs
def _srgb8_of(x, curve):
    """srgb(curve(x)) x 255 rounded, from the definitions: IEC 61966-2-1, and Narkowicz's ACES fit
    x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14) (clamp: min(max(x, 0), 1))."""
    x = np.maximum(np.asarray(x, np.float64), 0.0)
    y = np.clip(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14) if curve == "aces" else x, 0.0, 1.0)
    return np.floor(np.where(y <= 0.0031308, 12.92 * y, 1.055 * y ** (1 / 2.4) - 0.055) * 255 + 0.5)


def _png(path):
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"), np.int64)


def test_frame_png_takes_exposure_and_tone_curve_and_carries_metadata(baked, tmp_path):
    import wavlight
    from wavlight.imageio import read_metadata

    folder, out, stats = baked
    r = run("frame", out, "--rotate-y", 45, "-o", tmp_path / "lin.exr", "-q")
    assert r.exit_code == 0, r.output
    r = run("frame", out, "--rotate-y", 45, "-o", tmp_path / "f.png", "--exposure", 1.5, "--tonemap", "aces", "-q")
    assert r.exit_code == 0, r.output
    linear = _read_exr(tmp_path / "lin.exr")
    assert np.abs(_png(tmp_path / "f.png") - _srgb8_of(linear.astype(np.float64) * 2 ** 1.5, "aces")).max() <= 1
    meta = read_metadata(tmp_path / "f.png")
    assert (meta["strategy"], meta["spp"], meta["seed"]) == ("relit", str(stats["spp"]), "0")
    assert meta["scene_hash"] == stats["scene"]["content_hash"] and meta["version"] == wavlight.__version__
    assert (meta["exposure"], meta["tonemap"]) == ("1.5", "aces")
    assert read_metadata(tmp_path / "lin.exr")["scene_hash"] == stats["scene"]["content_hash"]
    r = run("frame", out, "--spp", 2, "--seed", 5, "-o", tmp_path / "u.exr", "-q")
    assert r.exit_code == 0, r.output
    meta = read_metadata(tmp_path / "u.exr")
    assert (meta["strategy"], meta["spp"], meta["seed"]) == ("unbiased", "2", "5")


def _read_exr(path):
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    try:
        return np.asarray(inp.read_image(format=oiio.FLOAT))
    finally:
        inp.close()


@pytest.mark.parametrize("args", [("--exposure", 1), ("--tonemap", "aces"), ("--spp", 2, "--tonemap", "aces")])
def test_frame_refuses_a_display_transform_for_a_linear_output(baked, tmp_path, args):
    _, out, _ = baked
    one_error_line(run("frame", out, "-o", tmp_path / "f.exr", *args), "f.exr", "linear")
    assert list(tmp_path.iterdir()) == []


def test_turntable_animations_hold_the_frames(baked, tmp_path):
    """The APNG reads back as the PNG frames, pixel for pixel (lossless); the MP4 (with PyAV)
    has every frame at the frames' size (even: 16 x 12) and close to them (H.264 is lossy)."""
    from PIL import Image, ImageSequence

    _, out, _ = baked
    r = run("frame", out, "--turntable", 4, "-o", tmp_path / "tt", "--tonemap", "aces", "--exposure", -0.5, "--json")
    assert r.exit_code == 0, r.output
    folder = tmp_path / "tt"
    frames = [_png(folder / f"frame-{i:04d}.png") for i in range(4)]
    assert json.loads(r.stdout)["output"][-len(animations("turntable")):] == \
        [str(folder / n) for n in ["turntable.png", "turntable.mp4"][:len(animations("turntable"))]]
    with Image.open(folder / "turntable.png") as im:
        shown = [np.asarray(f.convert("RGB"), np.int64) for f in ImageSequence.Iterator(im)]
        assert im.info.get("loop") == 0
    assert len(shown) == 4 and all((a == b).all() for a, b in zip(shown, frames))
    if not animation.has_mp4():
        assert "note: no MP4 written" in r.stderr and "wavlight[video]" in r.stderr
        return
    import av

    with av.open(str(folder / "turntable.mp4")) as c:
        decoded = [f.to_ndarray(format="rgb24").astype(np.int64) for f in c.decode(video=0)]
    assert len(decoded) == 4 and decoded[0].shape == (12, 16, 3)
    assert all(np.abs(d - f).mean() < 12 for d, f in zip(decoded, frames))


def test_turntable_without_pyav_writes_the_apng_and_one_note(baked, tmp_path, monkeypatch):
    monkeypatch.setattr(animation, "has_mp4", lambda: False)
    _, out, _ = baked
    r = run("frame", out, "--turntable", 2, "-o", tmp_path / "tt")
    assert r.exit_code == 0, r.output
    assert sorted(os.listdir(tmp_path / "tt")) == ["frame-0000.png", "frame-0001.png", "turntable.png"]
    notes = [line for line in r.stderr.splitlines() if line.startswith("note:")]
    assert notes == [f"note: {animation.NO_MP4_NOTE}"] and "'video' extra" in notes[0]


def test_odd_frames_make_an_even_mp4(tmp_path):
    """yuv420p halves the chroma: a 5 x 3 frame is padded to 6 x 4 by repeating its edge."""
    pytest.importorskip("av")
    import av
    from PIL import Image

    rgb = np.random.default_rng(1).integers(0, 256, (3, 5, 3), np.uint8)
    Image.fromarray(rgb).save(tmp_path / "a.png")
    animation.write_mp4([tmp_path / "a.png"] * 3, tmp_path / "a.mp4")
    with av.open(str(tmp_path / "a.mp4")) as c:
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(frames) == 3 and frames[0].shape == (4, 6, 3)


@pytest.mark.parametrize("value", ["nan", "inf", "30"])
def test_a_bad_exposure_is_one_line_before_any_work(baked, tmp_path, value):
    _, out, _ = baked
    one_error_line(run("frame", out, "--turntable", 2, "-o", tmp_path / "tt", "--exposure", value), "exposure")
    one_error_line(run("render", out.parent / "scene.toml", "-o", tmp_path / "r.png", "--exposure", value),
                   "exposure")
    assert list(tmp_path.iterdir()) == []
