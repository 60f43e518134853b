"""The `wavlight` command line, end to end.

A handful of tests run the installed console script in a subprocess (OpenCL start-up makes
each render ~1.5 s); the many input-validation and output-format cases use click's CliRunner
in-process (fast once OpenCL is up). Images are tiny (<= 16 x 12, 2-4 spp).

The contract: bad input -> exit code 2, one line "Error: ..." naming the file (and, for scene
errors, the key), no traceback, no output file or temporary left behind. Bad texels -> one
"warning: ..." line, never NaN in the output. Output format follows the extension.
"""
from __future__ import annotations

import json
import tomllib
import os
import re
import shutil
import subprocess
import sys
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import wavlight
from scenes_util import write_raw_image
from wavlight.cli.main import main

REPO = Path(__file__).resolve().parents[2]
DEFAULT_SCENE = REPO / "scenes" / "default.toml"
JSON_KEYS = ("strategy", "spp", "width", "height", "setup_seconds", "render_seconds", "samples_per_second")


# ----------------------------------------------------------------------------- running the CLI
def _command():
    exe = Path(sys.executable).with_name("wavlight")
    if exe.is_file():
        return [str(exe)]
    found = shutil.which("wavlight")
    return [found] if found else [sys.executable, "-m", "cli.main"]


@dataclass
class Outcome:
    code: int
    stdout: str
    stderr: str
    exception: BaseException | None = None

    def describe(self):
        tb = "".join(traceback.format_exception(self.exception)) if self.exception else ""
        return f"exit {self.code}\n--- stdout\n{self.stdout}\n--- stderr\n{self.stderr}\n{tb}"


def run_process(*args, cwd=None) -> Outcome:
    """The installed console script in a fresh process (the real thing users run)."""
    p = subprocess.run(_command() + [str(a) for a in args], capture_output=True, text=True,
                       cwd=cwd, timeout=300, env={**os.environ, "PYTHONWARNINGS": ""})
    return Outcome(p.returncode, p.stdout, p.stderr)


def run_inproc(*args) -> Outcome:
    """The same command through click's CliRunner (an escaping exception is kept in .exception)."""
    r = CliRunner().invoke(main, [str(a) for a in args])
    exc = r.exception if r.exception is not None and not isinstance(r.exception, SystemExit) else None
    return Outcome(r.exit_code, r.stdout, r.stderr, exc)


def stderr_lines(o: Outcome):
    return [line for line in o.stderr.splitlines() if line.strip()]


def assert_clean_failure(o: Outcome, *names, output=None, folder=None):
    """Exit 2, exactly one non-warning stderr line, starting with 'Error:' and naming every name."""
    assert o.exception is None, o.describe()
    assert "Traceback" not in o.stderr, o.describe()
    assert o.code == 2, o.describe()
    assert o.stdout == "", o.describe()
    errors = [line for line in stderr_lines(o) if not line.startswith("warning:")]
    assert len(errors) == 1, o.describe()
    assert errors[0].startswith("Error: "), o.describe()
    for name in names:
        assert str(name) in errors[0], f"{name!r} not named\n{o.describe()}"
    if output is not None:
        assert not Path(output).exists(), f"{output} left behind\n{o.describe()}"
    if folder is not None:
        left = [p.name for p in Path(folder).iterdir() if p.name.startswith(".wavlight-")]
        assert not left, f"temporary files left behind: {left}"
    return errors[0]


def assert_success(o: Outcome, code: int = 0):
    """Finished without an exception; code 3 (SANITISED_EXIT_CODE): finished on sanitised input."""
    assert o.exception is None, o.describe()
    assert "Traceback" not in o.stderr, o.describe()
    assert o.code == code, o.describe()


def assert_sanitised(o: Outcome):
    """Finished and wrote its output, but the input was sanitised: exit code 3, no Error line."""
    from wavlight.errors import SANITISED_EXIT_CODE

    assert SANITISED_EXIT_CODE == 3
    assert_success(o, SANITISED_EXIT_CODE)
    assert not [line for line in stderr_lines(o) if line.startswith("Error")], o.describe()


# ----------------------------------------------------------------------------- files
write_env = write_raw_image  # scenes_util


def write_pfm(path, pixels):
    """A PFM by the spec, by hand: little-endian, scanlines bottom to top."""
    pixels = np.asarray(pixels, np.float32)
    h, w = pixels.shape[:2]
    body = np.ascontiguousarray(pixels[::-1]).astype("<f4").tobytes()
    Path(path).write_bytes(f"PF\n{w} {h}\n-1.0\n".encode() + body)
    return path


def read_pfm(path):
    """A PFM by the spec, by hand (independent of OpenImageIO): row 0 of the result is the top."""
    data = Path(path).read_bytes()
    parts = data.split(maxsplit=4)  # b"PF", w, h, scale, rest
    assert parts[0] == b"PF", parts[0]
    w, h, scale = int(parts[1]), int(parts[2]), float(parts[3])
    body = data[len(data) - w * h * 12:]
    px = np.frombuffer(body, "<f4" if scale < 0 else ">f4").reshape(h, w, 3)
    return px[::-1].astype(np.float32)


def read_image(path):
    """(pixels, spec) with pixels float32 for float files and uint8 for 8-bit ones."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    fmt = oiio.UINT8 if spec.format == oiio.UINT8 else oiio.FLOAT
    px = np.asarray(inp.read_image(format=fmt)).reshape(spec.height, spec.width, spec.nchannels)
    inp.close()
    if str(path).lower().endswith(".pfm"):
        px = read_pfm(path)
    return px, spec


def write_scene(folder, text, name="scene.toml"):
    path = Path(folder) / name
    path.write_text(text)
    return path


def scene_text(env='procedural = "sky"', render="width = 8\nheight = 6\nspp = 2\n", objects=None,
               camera=None, extra=""):
    objects = objects if objects is not None else (
        '[[objects]]\nshape = "sphere"\ncenter = [0.0, 0.5, 0.0]\nradius = 0.5\nsubdivisions = 2\n'
        'material = "m"\n[[objects]]\nshape = "quad"\nsize = 4.0\n'
        '[materials.m]\ntype = "ggx"\nalbedo = [0.9, 0.8, 0.5]\nroughness = 0.3\n')
    camera = camera or 'eye = [0.0, 1.0, 3.0]\ntarget = [0.0, 0.4, 0.0]\n'
    return f"[render]\n{render}\n[camera]\n{camera}\n[environment]\n{env}\n{objects}\n{extra}"


def bad_texel_env(h=8, w=16):
    px = np.random.default_rng(5).uniform(0.2, 3.0, (h, w, 3)).astype(np.float32)
    px[0, :, 0] = np.nan          # the whole top row: looking up sees NaN in red
    px[1, 3] = np.inf
    px[2, 5, 1] = -np.inf
    px[3, 7:10, 2] = -2.0
    px[5, ::2] = np.nan           # below the horizon too, where the floor's shading samples
    return px


def no_temporaries(folder):
    return [p.name for p in Path(folder).iterdir() if p.name.startswith(".wavlight-")]


# ============================================================================= end to end (subprocess)
def test_e2e_default_scene_png_json(tmp_path):
    out = tmp_path / "default.png"
    o = run_process("render", DEFAULT_SCENE, "-o", out, "--width", 16, "--height", 12, "--spp", 2, "--json",
                    cwd=tmp_path)
    assert_success(o)
    assert o.stdout.count("\n") == 1 and o.stdout.endswith("\n"), o.describe()  # one object, one line
    stats = json.loads(o.stdout)
    assert isinstance(stats, dict)
    for k in JSON_KEYS:
        assert k in stats, f"missing {k}: {stats}"
    assert (stats["width"], stats["height"], stats["spp"]) == (16, 12, 2)
    with open(DEFAULT_SCENE, "rb") as fh:
        render = tomllib.load(fh)["render"]
    assert stats["strategy"] == render["strategy"] == "wavelet"   # from the scene: the product sampler
    assert stats["seed"] == render["seed"]
    for k in ("setup_seconds", "render_seconds", "samples_per_second"):
        assert isinstance(stats[k], (int, float)) and stats[k] >= 0, (k, stats[k])
    assert stats["samples_per_second"] > 0
    assert not [line for line in stderr_lines(o) if line.startswith("warning:")], o.describe()
    px, spec = read_image(out)
    assert (spec.width, spec.height, spec.nchannels) == (16, 12, 3)
    assert px.dtype == np.uint8
    assert px.std() > 0, "a flat image from the default scene"
    assert no_temporaries(tmp_path) == []


def test_e2e_flags_override_the_scene(tmp_path):
    out = tmp_path / "o.exr"
    o = run_process("render", DEFAULT_SCENE, "-o", out, "--spp", 3, "--strategy", "cosine", "--width", 10,
                    "--height", 7, "--seed", 3, "--json", cwd=tmp_path)
    assert_success(o)
    stats = json.loads(o.stdout)
    assert (stats["width"], stats["height"], stats["spp"], stats["strategy"]) == (10, 7, 3, "cosine")
    if "seed" in stats:
        assert stats["seed"] == 3
    px, spec = read_image(out)
    assert (spec.width, spec.height) == (10, 7)
    assert np.all(np.isfinite(px))


def test_e2e_exr_round_trips_linear_values(tmp_path):
    """No geometry: every camera ray sees the constant environment, so every pixel is exactly it,
    values above 1 included (no tone curve, no clamping for linear formats)."""
    color = np.array([0.25, 1.5, 37.0], np.float32)
    write_env(tmp_path / "env.exr", np.broadcast_to(color, (4, 8, 3)))
    scene = write_scene(tmp_path, scene_text(env='file = "env.exr"\nscale = 2.0', objects=""))
    out = tmp_path / "flat.exr"
    assert_success(run_process("render", scene, "-o", out, "-q", cwd=tmp_path))
    px, spec = read_image(out)
    assert (spec.width, spec.height, spec.nchannels) == (8, 6, 3)
    assert px.dtype == np.float32
    np.testing.assert_allclose(px, np.broadcast_to(2.0 * color, px.shape), rtol=1e-6)


def test_e2e_nan_texels_never_reach_the_exr(tmp_path):
    write_env(tmp_path / "bad.exr", bad_texel_env())
    scene = write_scene(tmp_path, scene_text(env='file = "bad.exr"', render="width = 12\nheight = 8\nspp = 4\n",
                                             camera='eye = [0.0, 0.6, 3.0]\ntarget = [0.0, 0.6, 0.0]\nfov_y = 90.0\n'))
    out = tmp_path / "out.exr"
    o = run_process("render", scene, "-o", out, cwd=tmp_path)
    assert_sanitised(o)
    warns = [line for line in stderr_lines(o) if line.startswith("warning:")]
    assert len(warns) == 1, o.describe()
    assert "bad.exr" in warns[0]
    px, _ = read_image(out)
    assert np.all(np.isfinite(px)), "NaN/Inf in the output"
    assert px.min() >= 0
    assert px.max() > 0


BAD_E2E = {
    "malformed toml": ("[render\nspp = 2\n", (), ("scene.toml",)),
    "spp zero in the scene": (scene_text(render="spp = 0\n"), (), ("scene.toml", "[render].spp")),
    "missing environment file": (scene_text(env='file = "nowhere.hdr"'), (), ("scene.toml", "[environment].file", "nowhere.hdr")),
    "all-black environment": (scene_text(env='procedural = "sky"\nscale = 0.0'), (), ("scene.toml", "[environment]")),
    "unsupported output extension": (scene_text(), ("-o", "{tmp}/out.jpg"), ("out.jpg",)),
    "absurd resolution": (scene_text(), ("--width", 100000, "--height", 100000), ("100000",)),
}


@pytest.mark.parametrize("case", list(BAD_E2E))
def test_e2e_bad_input(tmp_path, case):
    text, args, names = BAD_E2E[case]
    scene = write_scene(tmp_path, text)
    args = [str(a).format(tmp=tmp_path) for a in args]
    out = args[args.index("-o") + 1] if "-o" in args else tmp_path / "out.png"
    if "-o" not in args:
        args += ["-o", str(out)]
    o = run_process("render", scene, *args, "--json", cwd=tmp_path)
    assert_clean_failure(o, *names, output=out, folder=tmp_path)


def test_e2e_missing_scene_file(tmp_path):
    o = run_process("render", tmp_path / "nope.toml", "-o", tmp_path / "x.png", cwd=tmp_path)
    assert_clean_failure(o, "nope.toml", output=tmp_path / "x.png", folder=tmp_path)


def test_e2e_negative_seed_is_not_a_crash(tmp_path):
    """--seed -1 is an int click accepts: it must render, or be refused with a one-line error."""
    scene = write_scene(tmp_path, scene_text())
    out = tmp_path / "o.png"
    o = run_process("render", scene, "-o", out, "--seed", -1, cwd=tmp_path)
    assert "Traceback" not in o.stderr, o.describe()
    if o.code == 2:
        assert_clean_failure(o, "seed", output=out, folder=tmp_path)
    else:
        assert_success(o)
        assert out.is_file()


def test_e2e_info():
    o = run_process("info")
    assert_success(o)
    text = o.stdout
    assert f"wavlight {wavlight.__version__}" in text
    for word in ("python", "numpy", "pyopencl", "device in use:", "OpenCL builtins: "):
        assert word in text, o.describe()
    assert re.search(r"^\s+\[\d+:\d+\] \S", text, re.M), o.describe()  # the platform/device list


# ============================================================================= in-process (CliRunner)
def test_json_is_one_object_and_nothing_else_on_stdout(tmp_path):
    scene = write_scene(tmp_path, scene_text())
    o = run_inproc("render", scene, "-o", tmp_path / "a.png", "--json")
    assert_success(o)
    assert len(o.stdout.strip().splitlines()) == 1
    stats = json.loads(o.stdout)
    assert set(JSON_KEYS) <= set(stats)
    # without --json nothing at all goes to stdout (the summary is on stderr)
    o = run_inproc("render", scene, "-o", tmp_path / "b.png")
    assert_success(o)
    assert o.stdout == ""
    assert "b.png" in o.stderr
    # --quiet: silence on success
    o = run_inproc("render", scene, "-o", tmp_path / "c.png", "-q")
    assert_success(o)
    assert o.stdout == "" and o.stderr == ""


def test_scene_settings_apply_without_flags_and_flags_override(tmp_path):
    scene = write_scene(tmp_path, scene_text(render='width = 6\nheight = 4\nspp = 3\nstrategy = "uniform"\nseed = 5\n'))
    o = run_inproc("render", scene, "-o", tmp_path / "a.exr", "--json")
    assert_success(o)
    s = json.loads(o.stdout)
    assert (s["width"], s["height"], s["spp"], s["strategy"], s.get("seed", 5)) == (6, 4, 3, "uniform", 5)
    assert read_image(tmp_path / "a.exr")[1].width == 6
    for flags, want in [(("--spp", 2), ("spp", 2)), (("--strategy", "light"), ("strategy", "light")),
                        (("--width", 5), ("width", 5)), (("--height", 3), ("height", 3)),
                        (("--seed", 9), ("seed", 9)), (("--sampler", "stratified"), ("sampler", "stratified"))]:
        o = run_inproc("render", scene, "-o", tmp_path / "b.exr", "--json", *flags)
        assert_success(o)
        s = json.loads(o.stdout)
        if want[0] in s:
            assert s[want[0]] == want[1], (flags, s)
        _, spec = read_image(tmp_path / "b.exr")
        assert (spec.width, spec.height) == (s["width"], s["height"])


@pytest.mark.parametrize("strategy", ["uniform", "cosine", "bsdf", "light", "mis", "mis_comp"])
def test_every_strategy_flag_renders(tmp_path, strategy):
    scene = write_scene(tmp_path, scene_text())
    o = run_inproc("render", scene, "-o", tmp_path / "a.exr", "--strategy", strategy, "--json")
    assert_success(o)
    assert json.loads(o.stdout)["strategy"] == strategy
    px, _ = read_image(tmp_path / "a.exr")
    assert np.all(np.isfinite(px)) and px.min() >= 0 and px.max() > 0


def test_same_seed_same_image_other_seed_other_noise(tmp_path):
    scene = write_scene(tmp_path, scene_text(render='width = 8\nheight = 6\nspp = 2\nstrategy = "uniform"\n'))
    for name, seed in (("a", 1), ("b", 1), ("c", 2)):
        assert_success(run_inproc("render", scene, "-o", tmp_path / f"{name}.exr", "--seed", seed, "-q"))
    a, b, c = (read_image(tmp_path / f"{n}.exr")[0] for n in "abc")
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_default_output_name_is_the_scene_name_png(tmp_path, monkeypatch):
    scene = write_scene(tmp_path, scene_text(), name="myscene.toml")
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    monkeypatch.chdir(run_dir)
    assert_success(run_inproc("render", scene, "-q"))
    _, spec = read_image(run_dir / "myscene.png")
    assert (spec.width, spec.height) == (8, 6)


# ----------------------------------------------------------------------------- output formats
def _srgb8(x):
    x = min(max(x, 0.0), 1.0)
    s = 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055
    return int(s * 255 + 0.5)


@pytest.mark.parametrize("ext", [".exr", ".pfm", ".hdr", ".png", ".EXR"])
def test_output_format_follows_the_extension(tmp_path, ext):
    color = np.array([0.002, 0.2, 3.5], np.float32)
    write_env(tmp_path / "env.exr", np.broadcast_to(color, (4, 8, 3)))
    scene = write_scene(tmp_path, scene_text(env='file = "env.exr"', objects=""))
    out = tmp_path / f"o{ext}"
    assert_success(run_inproc("render", scene, "-o", out, "-q"))
    px, spec = read_image(out)
    assert (spec.width, spec.height, spec.nchannels) == (8, 6, 3)
    if ext.lower() == ".png":
        assert px.dtype == np.uint8
        assert px.reshape(-1, 3).tolist() == [[_srgb8(float(c)) for c in color]] * 48
        return
    assert px.dtype == np.float32
    want = np.broadcast_to(color, px.shape)
    if ext == ".hdr":  # RGBE: 8-bit mantissas with a shared exponent
        assert np.abs(px - want).max() <= 0.01 * color.max()
    else:
        np.testing.assert_allclose(px, want, rtol=1e-6)
    head = out.read_bytes()[:10]
    magic = {".exr": b"\x76\x2f\x31\x01", ".pfm": b"PF", ".hdr": b"#?"}[ext.lower()]
    assert head.startswith(magic), head


def test_png_takes_exposure_and_tone_curve_and_both_carry_metadata(tmp_path):
    """The PNG is srgb(curve(x 2^EV)) of the same render's linear pixels (the formulas written
    out: IEC 61966-2-1 and Narkowicz's ACES fit); both files hold the render's provenance."""
    import wavlight
    from wavlight.imageio import read_metadata

    scene = write_scene(tmp_path, scene_text())
    assert_success(run_inproc("render", scene, "-o", tmp_path / "a.exr", "--seed", 3, "-q"))
    assert_success(run_inproc("render", scene, "-o", tmp_path / "a.png", "--seed", 3, "--exposure", "0.75",
                              "--tonemap", "aces", "--stderr-out", tmp_path / "se.exr", "-q"))
    linear = read_image(tmp_path / "a.exr")[0].astype(np.float64) * 2 ** 0.75
    y = np.clip(linear * (2.51 * linear + 0.03) / (linear * (2.43 * linear + 0.59) + 0.14), 0.0, 1.0)
    want = np.floor(np.where(y <= 0.0031308, 12.92 * y, 1.055 * y ** (1 / 2.4) - 0.055) * 255 + 0.5)
    assert np.abs(read_image(tmp_path / "a.png")[0].astype(int) - want).max() <= 1
    scene_hash = wavlight.load_scene(scene).content_hash
    for name in ("a.exr", "a.png", "se.exr"):
        meta = read_metadata(tmp_path / name)
        assert {k: meta[k] for k in ("strategy", "spp", "seed", "scene_hash", "version")} == \
            {"strategy": "mis", "spp": "2", "seed": "3", "scene_hash": scene_hash, "version": wavlight.__version__}
    assert (read_metadata(tmp_path / "a.png")["tonemap"], read_metadata(tmp_path / "a.png")["exposure"]) == \
        ("aces", "0.75")
    # the standard error stays linear: its pixels are not the PNG's transform
    assert read_image(tmp_path / "se.exr")[0].dtype == np.float32


@pytest.mark.parametrize("ext", [".exr", ".hdr", ".pfm"])
def test_linear_output_refuses_exposure_and_tone_curve(tmp_path, ext):
    scene = write_scene(tmp_path, scene_text())
    for args in (("--exposure", "1"), ("--tonemap", "aces")):
        assert_clean_failure(run_inproc("render", scene, "-o", tmp_path / f"a{ext}", *args), f"a{ext}", "linear",
                             output=tmp_path / f"a{ext}")
    assert_success(run_inproc("render", scene, "-o", tmp_path / f"a{ext}", "--exposure", "0", "-q"))


def _orientation_env(h=4, w=8):
    """Top half (+Y) bright, bottom half dim; column 0 (just right of -Z) green, column w-1 red."""
    base = np.full((w, 3), 0.5, np.float32)
    base[0] = [0.1, 1.0, 0.1]
    base[w - 1] = [1.0, 0.1, 0.1]
    return np.concatenate([np.broadcast_to(4.0 * base, (h // 2, w, 3)),
                           np.broadcast_to(0.25 * base, (h - h // 2, w, 3))]).astype(np.float32)


@pytest.mark.parametrize("env_ext, out_ext", [("exr", ".exr"), ("exr", ".pfm"), ("pfm", ".exr")])
def test_image_orientation_through_files(tmp_path, env_ext, out_ext):
    """Looking down -Z with up = +Y and no geometry: the top of the image sees the top of the map,
    the right of the image sees +X (map column 0, u = atan2(x, -z) / 2pi just above 0), the left
    sees the last column. Checks the environment reader, the camera and the writer together; the
    .pfm files are read and written by hand, by the spec (scanlines bottom to top)."""
    env = _orientation_env()
    (write_pfm if env_ext == "pfm" else write_env)(tmp_path / f"env.{env_ext}", env)
    scene = write_scene(tmp_path, scene_text(env=f'file = "env.{env_ext}"', objects="",
                                             render="width = 8\nheight = 8\nspp = 4\n",
                                             camera='eye = [0.0, 0.0, 0.0]\ntarget = [0.0, 0.0, -1.0]\n'
                                                    'up = [0.0, 1.0, 0.0]\nfov_y = 90.0\n'))
    out = tmp_path / f"o{out_ext}"
    assert_success(run_inproc("render", scene, "-o", out, "-q"))
    px = read_pfm(out) if out_ext == ".pfm" else read_image(out)[0]
    w = env.shape[1]
    np.testing.assert_allclose(px[:4, 4:], np.broadcast_to(env[0, 0], (4, 4, 3)), rtol=1e-6)   # top right
    np.testing.assert_allclose(px[:4, :4], np.broadcast_to(env[0, w - 1], (4, 4, 3)), rtol=1e-6)  # top left
    np.testing.assert_allclose(px[4:, 4:], np.broadcast_to(env[-1, 0], (4, 4, 3)), rtol=1e-6)  # bottom right
    np.testing.assert_allclose(px[4:, :4], np.broadcast_to(env[-1, w - 1], (4, 4, 3)), rtol=1e-6)


def test_output_file_gets_the_usual_permissions(tmp_path):
    """The atomic write goes through a temporary file; the result must still be an ordinary file
    (mode 0666 & ~umask, like any file the user creates), not mkstemp's private 0600."""
    scene = write_scene(tmp_path, scene_text())
    out = tmp_path / "o.png"
    assert_success(run_inproc("render", scene, "-o", out, "-q"))
    umask = os.umask(0)
    os.umask(umask)
    assert oct(out.stat().st_mode & 0o777) == oct(0o666 & ~umask)


def test_failed_write_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    """Atomic output: a writer that fails half way leaves the previous file untouched."""
    import OpenImageIO as oiio

    out = tmp_path / "o.exr"
    out.write_bytes(b"previous")

    class HalfWriter:
        @staticmethod
        def create(name):
            return HalfWriter(name)

        def __init__(self, name):
            self.name = name

        def open(self, name, spec):
            Path(name).write_bytes(b"\x76\x2f\x31\x01 partial")
            return True

        def write_image(self, pixels):
            return False

        def geterror(self):
            return "disk full"

        def close(self):
            return True

    scene = write_scene(tmp_path, scene_text())
    monkeypatch.setattr(oiio, "ImageOutput", HalfWriter)
    o = run_inproc("render", scene, "-o", out)
    monkeypatch.undo()
    assert_clean_failure(o, "o.exr", folder=tmp_path)
    assert out.read_bytes() == b"previous"
    # and a failure before anything is written leaves nothing at all
    new = tmp_path / "new.exr"
    monkeypatch.setattr(oiio, "ImageOutput", HalfWriter)
    o = run_inproc("render", scene, "-o", new)
    monkeypatch.undo()
    assert_clean_failure(o, "new.exr", output=new, folder=tmp_path)


def test_output_path_is_a_folder(tmp_path):
    scene = write_scene(tmp_path, scene_text())
    (tmp_path / "taken.png").mkdir()
    o = run_inproc("render", scene, "-o", tmp_path / "taken.png")
    assert_clean_failure(o, "taken.png", folder=tmp_path)
    assert (tmp_path / "taken.png").is_dir()


def test_output_folder_missing(tmp_path, monkeypatch):
    """Refused before rendering (a long render would otherwise be thrown away at the end)."""
    import wavlight

    scene = write_scene(tmp_path, scene_text())
    out = tmp_path / "no" / "such" / "dir" / "o.exr"
    monkeypatch.setattr(wavlight, "render_full", lambda *a, **k: pytest.fail("rendered before checking the output"))
    assert_clean_failure(run_inproc("render", scene, "-o", out), "o.exr", output=out, folder=tmp_path)


def test_stderr_out_writes_the_standard_error_image(tmp_path):
    """--stderr-out writes render_full's per-pixel standard error (linear), next to the image."""
    import wavlight

    scene = write_scene(tmp_path, scene_text(render="width = 8\nheight = 6\nspp = 8\nseed = 4\n"))
    out, se = tmp_path / "o.exr", tmp_path / "se.exr"
    o = run_inproc("render", scene, "-o", out, "--stderr-out", se, "--json")
    assert_success(o)
    assert json.loads(o.stdout)["stderr_output"] == str(se)
    got = read_image(se)[0]
    ref = wavlight.render_full(wavlight.load_scene(str(scene)))
    np.testing.assert_array_equal(read_image(out)[0], ref.image)
    np.testing.assert_array_equal(got, ref.stderr)
    assert np.all(np.isfinite(got)) and got.min() >= 0 and got.max() > 0


def test_stderr_out_that_cannot_be_written_leaves_no_image(tmp_path, monkeypatch):
    """The image and its standard errors appear together or not at all: when the second write
    fails (here the standard-error writer reports an error), exit 2, one line, and no image."""
    import OpenImageIO as oiio

    scene = write_scene(tmp_path, scene_text(render="width = 8\nheight = 6\nspp = 4\n"))
    out, se = tmp_path / "o.exr", tmp_path / "se.pfm"
    real_create = oiio.ImageOutput.create

    class Failing:   # a writer whose pixels do not get written
        def __init__(self, inner):
            self.inner = inner

        def open(self, *a):
            return self.inner.open(*a)

        def write_image(self, *a):
            return False

        def geterror(self):
            return "no space left on device"

        def close(self):
            return self.inner.close()

    def create(path):
        return Failing(real_create(path)) if str(path).endswith(".pfm") else real_create(path)

    monkeypatch.setattr(oiio.ImageOutput, "create", create)
    o = run_inproc("render", scene, "-o", out, "--stderr-out", se)
    assert_clean_failure(o, "se.pfm", output=out, folder=tmp_path)
    assert not se.exists()


@pytest.mark.parametrize("args, name", [(("--stderr-out", "{tmp}/se.png"), "se.png"),
                                        (("--stderr-out", "{tmp}/se.exr", "--spp", "1"), "spp >= 2"),
                                        (("--stderr-out", "{tmp}/o.exr"), "must differ")])
def test_stderr_out_bad_use_is_one_line(tmp_path, args, name):
    scene = write_scene(tmp_path, scene_text())
    out = tmp_path / "o.exr"
    o = run_inproc("render", scene, "-o", out, *[a.format(tmp=tmp_path) for a in args])
    assert_clean_failure(o, name, output=out, folder=tmp_path)


def test_output_that_is_a_folder_or_read_only_is_refused(tmp_path):
    """-o naming a folder says so (before the extension check), and a read-only output file is
    refused, not replaced by the atomic rename; both in one line, leaving them as they were."""
    scene = write_scene(tmp_path, scene_text())
    folder = tmp_path / "sub"
    folder.mkdir()
    assert_clean_failure(run_inproc("render", scene, "-o", folder), "is a folder")
    assert folder.is_dir()
    locked = tmp_path / "locked.exr"
    locked.write_bytes(b"keep")
    locked.chmod(0o444)
    assert_clean_failure(run_inproc("render", scene, "-o", locked), "read-only")
    assert locked.read_bytes() == b"keep"


def test_overflowed_render_is_one_line_and_writes_nothing(tmp_path, monkeypatch):
    """Finite, bounded inputs can still overflow an estimate (a near-mirror lobe seen by uniform
    sampling under a sun of 1e30): the command says so, in one line, and writes nothing."""
    import wavlight

    real = wavlight.render_full

    def overflowing(*a, **k):
        r = real(*a, **k)
        r.image[0, 0, 1] = np.inf
        return r

    scene = write_scene(tmp_path, scene_text())
    out = tmp_path / "o.exr"
    monkeypatch.setattr(wavlight, "render_full", overflowing)
    assert_clean_failure(run_inproc("render", scene, "-o", out), "overflowed", output=out, folder=tmp_path)


def test_seed_beyond_63_bits_is_refused(tmp_path):
    """The scene file caps seed at 2^63 - 1; so does --seed (numbers past 2^64 once wrapped to 0)."""
    scene = write_scene(tmp_path, scene_text())
    out = tmp_path / "o.png"
    assert_clean_failure(run_inproc("render", scene, "-o", out, "--seed", 2 ** 64), "--seed", output=out,
                         folder=tmp_path)


# ----------------------------------------------------------------------------- bad texels
@pytest.mark.parametrize("strategy", ["uniform", "cosine", "bsdf", "light", "mis", "mis_comp"])
def test_bad_texels_warn_once_and_never_reach_the_output(tmp_path, strategy):
    write_env(tmp_path / "bad.exr", bad_texel_env())
    scene = write_scene(tmp_path, scene_text(env='file = "bad.exr"\nrotate_y = 20.0',
                                             camera='eye = [0.0, 0.6, 3.0]\ntarget = [0.0, 0.6, 0.0]\n'
                                                    'fov_y = 100.0\n'))
    out = tmp_path / "o.exr"
    o = run_inproc("render", scene, "-o", out, "--strategy", strategy, "--spp", 4)
    assert_sanitised(o)
    warns = [line for line in stderr_lines(o) if line.startswith("warning:")]
    assert len(warns) == 1 and "bad.exr" in warns[0], o.describe()
    assert not [line for line in stderr_lines(o) if line.startswith("Error")]
    px, _ = read_image(out)
    assert np.all(np.isfinite(px)) and px.min() >= 0


def test_sanitised_exit_code_survives_an_earlier_warning_in_the_process(tmp_path):
    """Python shows a warning once per location: a library load of the same bad map earlier in
    the process (or -W ignore) must not hide it from the command, nor its exit code 3."""
    import warnings

    import wavlight

    write_env(tmp_path / "bad.exr", bad_texel_env())
    scene = write_scene(tmp_path, scene_text(env='file = "bad.exr"'))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        wavlight.load_scene(scene)                     # the library's own load: silenced
        warnings.simplefilter("default")
        wavlight.load_scene(scene)                     # shown once here, registered
        for _ in range(2):                             # then twice through the CLI
            o = run_inproc("render", scene, "-o", tmp_path / "o.exr", "-q")
            assert_sanitised(o)
            warns = [line for line in stderr_lines(o) if line.startswith("warning:")]
            assert len(warns) == 1 and "bad.exr" in warns[0], o.describe()
        warnings.simplefilter("ignore")                # a user's -W ignore
        assert_sanitised(run_inproc("render", scene, "-o", tmp_path / "o.exr", "-q"))


def test_environment_of_only_bad_texels_is_black(tmp_path):
    env = np.full((4, 8, 3), np.nan, np.float32)
    env[1] = -1.0
    env[2] = np.inf
    write_env(tmp_path / "bad.exr", env)
    scene = write_scene(tmp_path, scene_text(env='file = "bad.exr"'))
    out = tmp_path / "o.exr"
    o = run_inproc("render", scene, "-o", out)
    msg = assert_clean_failure(o, "scene.toml", "[environment]", output=out, folder=tmp_path)
    assert "black" in msg
    assert len([line for line in stderr_lines(o) if line.startswith("warning:")]) == 1


# ----------------------------------------------------------------------------- bad input (in-process)
BAD = {
    # name: (scene text, extra args, names the error line must contain)
    "malformed toml": ("[render]\nspp = = 2\n", (), ("scene.toml",)),
    "unknown key": (scene_text(extra="[materials.m2]\ntype = \"lambert\"\nshine = 1.0\n"), (), ("scene.toml", "[materials.m2].shine")),
    "unknown table": ("[cameras]\nfov_y = 30.0\n" + scene_text(), (), ("scene.toml", "cameras")),
    "wrong type": (scene_text(render='width = "wide"\n'), (), ("scene.toml", "[render].width")),
    "wrong type in camera": (scene_text(camera="eye = [0.0, 1.0]\n"), (), ("scene.toml", "[camera].eye")),
    "unknown material": (scene_text(objects='[[objects]]\nshape = "quad"\nmaterial = "gold"\n'), (), ("scene.toml", "[[objects]][0].material", "gold")),
    "missing mesh file": (scene_text(objects='[[objects]]\nmesh = "bunny.ply"\n'), (), ("scene.toml", "[[objects]][0].mesh", "bunny.ply")),
    "missing environment file": (scene_text(env='file = "env/none.exr"'), (), ("scene.toml", "[environment].file", "none.exr")),
    "unreadable environment file": (scene_text(env='file = "junk.hdr"'), (), ("scene.toml", "[environment].file", "junk.hdr")),
    "spp zero in the scene": (scene_text(render="spp = 0\n"), (), ("scene.toml", "[render].spp")),
    "absurd resolution in the scene": (scene_text(render="width = 100000\nheight = 100000\n"), (), ("scene.toml", "[render].width")),
    "unknown strategy in the scene": (scene_text(render='strategy = "path"\n'), (), ("scene.toml", "[render].strategy")),
    "unknown sampler in the scene": (scene_text(render='sampler = "sobol"\n'), (), ("scene.toml", "[render].sampler", "sobol")),
    "one wavelet candidate in the scene": (scene_text(render="wavelet_candidates = 1\n"), (),
                                           ("scene.toml", "[render].wavelet_candidates")),
    "too many wavelet candidates in the scene": (scene_text(render="wavelet_candidates = 65\n"), (),
                                                 ("scene.toml", "[render].wavelet_candidates")),
    "one wavelet candidate on the command line": (scene_text(), ("--strategy", "wavelet", "--wavelet-candidates", 1),
                                                  ("--wavelet-candidates",)),
    "three wavelet slots in the scene": (scene_text(render="wavelet_slots = 3\n"), (),
                                         ("scene.toml", "[render].wavelet_slots")),
    "four slots for the MIS pair": (scene_text(), ("--strategy", "wavelet", "--wavelet-candidates", 0,
                                                   "--wavelet-slots", 4), ("wavelet_slots",)),
    "black environment (scale 0)": (scene_text(env='procedural = "sky"\nscale = 0.0'), (), ("scene.toml", "[environment]", "black")),
    "black environment (file)": (scene_text(env='file = "black.exr"'), (), ("scene.toml", "[environment]", "black")),
    "only degenerate triangles": (scene_text(objects='[[objects]]\nmesh = "flat.obj"\n'), (), ("scene.toml", "[[objects]][0]", "degenerate")),
    "--spp 0": (scene_text(), ("--spp", 0), ("--spp",)),
    "--spp negative": (scene_text(), ("--spp", -5), ("--spp",)),
    "--spp too many": (scene_text(), ("--spp", 10 ** 9), ("spp",)),
    "--width 0": (scene_text(), ("--width", 0), ("--width",)),
    "--height negative": (scene_text(), ("--height", -1), ("--height",)),
    "absurd resolution flags": (scene_text(), ("--width", 100000, "--height", 100000), ("100000",)),
    "unsupported extension": (scene_text(), ("-o", "{tmp}/o.tiff"), ("o.tiff",)),
    "no extension": (scene_text(), ("-o", "{tmp}/output"), ("output",)),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input(tmp_path, case):
    text, args, names = BAD[case]
    (tmp_path / "junk.hdr").write_bytes(b"not an image at all\n")
    write_env(tmp_path / "black.exr", np.zeros((4, 8, 3)))
    (tmp_path / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\nf 1 1 4\n")
    scene = write_scene(tmp_path, text)
    args = [str(a).format(tmp=tmp_path) for a in args]
    if "-o" in args:
        out = Path(args[args.index("-o") + 1])
    else:
        out = tmp_path / "out.exr"
        args += ["-o", str(out)]
    o = run_inproc("render", scene, *args, "--json")
    assert_clean_failure(o, *names, output=out, folder=tmp_path)


@pytest.mark.parametrize("args, name", [(("--strategy", "best"), "--strategy"), (("--width", "abc"), "--width"),
                                        (("--wavelet-levels", "99"), "--wavelet-levels"), (("--nope",), "--nope")])
def test_bad_option_is_one_line(tmp_path, args, name):
    """A click usage error: exit 2 and one 'Error:' line naming the option, with a --help hint
    (not click's usage block)."""
    scene = write_scene(tmp_path, scene_text())
    out = tmp_path / "o.png"
    o = run_inproc("render", scene, "-o", out, *args)
    assert o.exception is None and o.code == 2, o.describe()
    lines = stderr_lines(o)
    assert len(lines) == 1 and lines[0].startswith("Error:") and name in lines[0], lines
    assert "--help" in lines[0]
    assert not out.exists()


def test_library_messages_spanning_lines_print_as_one():
    from wavlight.cli.common import one_line as _one_line

    assert _one_line("file.pfm: bad header\n  size 0 x 0\n") == "file.pfm: bad header; size 0 x 0"


def test_scene_path_is_a_folder(tmp_path):
    o = run_inproc("render", tmp_path, "-o", tmp_path / "o.png")
    assert o.exception is None and o.code == 2, o.describe()
    assert not (tmp_path / "o.png").exists()


def test_negative_seed_in_the_scene_is_not_a_crash(tmp_path):
    """The scene loader accepts `seed = -1` (any integer): rendering it must work, or the loader
    must refuse it with an error naming [render].seed."""
    scene = write_scene(tmp_path, scene_text(render="width = 4\nheight = 4\nspp = 1\nseed = -1\n"))
    out = tmp_path / "o.png"
    o = run_inproc("render", scene, "-o", out, "-q")
    assert o.exception is None, o.describe()
    if o.code == 2:
        assert_clean_failure(o, "scene.toml", "[render].seed", output=out, folder=tmp_path)
    else:
        assert_success(o)
        assert out.is_file()


def test_degenerate_triangles_warn_and_render(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 4 5\n")
    scene = write_scene(tmp_path, scene_text(objects='[[objects]]\nmesh = "m.obj"\n'))
    out = tmp_path / "o.png"
    o = run_inproc("render", scene, "-o", out, "-q")
    assert_sanitised(o)
    warns = [line for line in stderr_lines(o) if line.startswith("warning:")]
    assert len(warns) == 1 and "degenerate" in warns[0] and "scene.toml" in warns[0], o.describe()
    assert out.is_file()


def test_other_warnings_keep_exit_code_0(tmp_path):
    """Only sanitised input sets exit code 3: an albedo above 1 warns but is rendered as asked."""
    scene = write_scene(tmp_path, scene_text(objects='[[objects]]\nshape = "sphere"\nmaterial = "m"\n'
                                                     '[materials.m]\ntype = "lambert"\nalbedo = [1.2, 0.5, 0.5]\n'))
    out = tmp_path / "o.exr"
    o = run_inproc("render", scene, "-o", out, "-q")
    assert_success(o)
    warns = [line for line in stderr_lines(o) if line.startswith("warning:")]
    assert len(warns) == 1 and "albedo: above 1" in warns[0], o.describe()
    assert out.is_file()


@pytest.mark.slow
def test_wavelet_candidates_from_scene_and_flag(tmp_path):
    """[render] wavelet_candidates reaches the strategy; --wavelet-candidates overrides it (--json)."""
    scene = write_scene(tmp_path, scene_text(render="width = 8\nheight = 6\nspp = 2\nstrategy = \"wavelet\"\n"
                                                    "wavelet_candidates = 4\n"))
    for args, want in (((), 4), (("--wavelet-candidates", 0), 0), (("--wavelet-candidates", 12), 12)):
        o = run_inproc("render", scene, "-o", tmp_path / "o.exr", "--json", *args)
        assert_success(o)
        assert json.loads(o.stdout)["wavelet_candidates"] == want, o.describe()


def test_wavelet_slots_from_scene_and_flag(tmp_path):
    """[render] wavelet_slots reaches the strategy; --wavelet-slots overrides it (--json); the
    four slots' directions are traced: slots a and b pick as with two (the same thresholds),
    so the shadow rays (rays less one camera ray per sample) grow, at most to twice."""
    scene = write_scene(tmp_path, scene_text(render="width = 8\nheight = 6\nspp = 2\nstrategy = \"wavelet\"\n"
                                                    "wavelet_slots = 4\n"))
    shadow = {}
    for args, want in (((), 4), (("--wavelet-slots", "2"), 2)):
        o = run_inproc("render", scene, "-o", tmp_path / "o.exr", "--json", *args)
        assert_success(o)
        stats = json.loads(o.stdout)
        assert stats["wavelet_slots"] == want, o.describe()
        shadow[want] = stats["rays"] - 8 * 6 * 2
    assert 0 < shadow[2] < shadow[4] <= 2 * shadow[2], shadow


def test_closing_message_names_the_wavelet_budget(tmp_path):
    """The closing line on stderr gives the wavelet strategy's candidates and slots (chosen
    from the scene or given), and nothing more for the MIS pair or another strategy."""
    scene = write_scene(tmp_path, scene_text(render="width = 8\nheight = 6\nspp = 2\nstrategy = \"wavelet\"\n"))
    for args, want in (((), " candidates, "), (("--wavelet-candidates", 6, "--wavelet-slots", "4"),
                                                 "wavelet (6 candidates, 4 slots)"),
                       (("--wavelet-candidates", 0), "wavelet, render"), (("--strategy", "mis"), "mis, render")):
        o = run_inproc("render", scene, "-o", tmp_path / "o.exr", *args)
        assert_success(o)
        closing = [line for line in stderr_lines(o) if line.startswith("wrote ")]
        assert len(closing) == 1 and want in closing[0], o.describe()


def test_wavelet_control_variate_flag(tmp_path):
    """--no-wavelet-control-variate reaches the strategy (--json wavelet_control_variate); it is
    on by default, and reported off for the MIS pair, which has no candidates."""
    scene = write_scene(tmp_path, scene_text(render="width = 8\nheight = 6\nspp = 2\nstrategy = \"wavelet\"\n"))
    for args, want in (((), True), (("--no-wavelet-control-variate",), False),
                       (("--wavelet-control-variate",), True), (("--wavelet-candidates", 0), False)):
        o = run_inproc("render", scene, "-o", tmp_path / "o.exr", "--json", *args)
        assert_success(o)
        assert json.loads(o.stdout)["wavelet_control_variate"] is want, o.describe()


def test_version_flag():
    o = run_inproc("--version")
    assert_success(o)
    assert wavlight.__version__ in o.stdout
