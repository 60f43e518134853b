"""One declaration per setting (wavlight.relight.settings, wavlight.options): the flags of `wavlight
bake`, `frame` and `view` show their records' defaults, the library's keywords default to the same
records, a flag left out leaves the library's default in place, and the docs' tables are the
records' (regenerated and compared)."""
from __future__ import annotations

import importlib.util
import inspect
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

import wavlight
from wavlight import imageio
from wavlight.cli.main import main
from wavlight.relight import converge, frames, moving, settings, transfer, view_frames, viewer

ROOT = Path(__file__).resolve().parents[1]

#: the library calls a command makes with the settings it was given, and the records whose keys
#: they take: a setting left out falls to that call's default
LIBRARY = {
    "bake": [(wavlight.bake, tuple(settings.BAKE))],
    "frame": [
        (frames.frames_for, ("scene", "background")),
        (transfer.Transfer.frame, ("env", "rotate_y", "scale", "terms", "priority", "background")),
        (transfer.Transfer.frame_timed, ("env", "rotate_y", "scale", "terms", "priority", "background")),
        (converge.converge, ("scene", "env", "rotate_y", "scale", "seed", "background")),
        (moving.MovingObject.frame, ("translate", "rotate", "spp", "seed")),
        (view_frames.still_settings, ("refine", "mass", "mode", "supersample", "tau")),
        # (mode and supersample default to the viewer's frame here: still_settings holds the written one's)
        (view_frames.ViewFrames.frame, ("eye", "target", "fov", "width", "height", "refine", "mass", "tau")),
        (view_frames.ViewFrames.converge, ("eye", "target", "fov", "width", "height", "seed")),
        (view_frames.ViewFrames.__init__, ("scene", "background")),
        (imageio.save_image, ("exposure", "tonemap")),
    ],
    "view": [(viewer.Viewer.__init__, ("maps", "scene", "background")), (viewer.Viewer.serve, ("port",))],
}
#: settings of the command itself, which no library call takes
COMMAND_ONLY = {"bake": set(), "frame": {"turntable", "repeat", "orbit"}, "view": {"no_browser"}}


def command(name) -> click.Command:
    return main.commands[name]


def param_of(cmd: click.Command, flag: str) -> click.Parameter:
    found = [p for p in cmd.params if flag in p.opts]
    assert len(found) == 1, flag
    return found[0]


@pytest.mark.parametrize("name", sorted(settings.COMMANDS))
def test_every_flag_shows_its_records_default(name):
    """Each record is a flag of the command whose help ends in its default and whose click
    default is None (or () / False): nothing but the record says what the default is."""
    cmd = command(name)
    shown = " ".join(CliRunner().invoke(main, [name, "--help"], terminal_width=200).output.split())
    for record in settings.COMMANDS[name].values():
        param = param_of(cmd, record.flag)
        text = f"Default: {record.default_text()}."
        assert param.help.endswith(text), (record.flag, param.help)
        assert " ".join(param.help.split()) in shown, record.flag
        assert param.default in (None, (), False), (record.flag, param.default)
        if record.values:
            assert list(param.type.choices) == [str(v) for v in record.values], record.flag
        elif isinstance(param.type, (click.IntRange, click.FloatRange)):
            assert (param.type.min, param.type.max) == (record.lo, record.hi), record.flag


@pytest.mark.parametrize("name", sorted(settings.COMMANDS))
def test_library_defaults_are_the_records(name):
    """The keywords of the calls a command makes default to the records' defaults, and every
    setting reaches one of them (or is the command's own)."""
    records = settings.COMMANDS[name]
    reached = set()
    for function, keys in LIBRARY[name]:
        parameters = inspect.signature(function).parameters
        for key in keys:
            assert key in parameters, (function.__qualname__, key)
            assert parameters[key].default == records[key].default, (function.__qualname__, key)
            reached.add(key)
    assert reached | COMMAND_ONLY[name] == set(records)


def test_the_written_frames_defaults():
    """still_settings() is the written frame view_frames.STILL: its records' defaults, and supersample's
    rule for the mode (point mode: one ray per pixel)."""
    records = settings.FRAME
    assert view_frames.STILL == {"refine": records["refine"].default, "mass": records["mass"].default,
                          "mode": records["mode"].default, "supersample": settings.WRITTEN_SUPERSAMPLE,
                          "tau": records["tau"].default}
    assert records["mode"].default == "pixel" and view_frames.still_settings(mode="point")["supersample"] == 1
    assert view_frames.still_settings(mode="point", supersample=3)["supersample"] == 3


def test_a_bake_without_flags_is_the_librarys_bake(monkeypatch, tmp_path):
    """`wavlight bake SCENE -o PATH` calls wavlight.bake with no setting of its own: the library's
    defaults are the command's; a flag given is passed on as given."""
    calls = []

    def fake(scene, output, **kwargs):
        calls.append(kwargs)
        raise wavlight.WavlightError("stop")

    monkeypatch.setattr(wavlight, "bake", fake)
    scene = str(ROOT / "scenes" / "default.toml")
    out = str(tmp_path / "x.wlt")
    r = CliRunner().invoke(main, ["bake", scene, "-o", out])
    assert r.exit_code == 2 and calls == [{"progress": None}], (r.output, calls)
    r = CliRunner().invoke(main, ["bake", scene, "-o", out, "--bits", "16", "--tolerance", "0.05", "--seed", "3"])
    assert r.exit_code == 2 and calls[-1] == {"progress": None, "bits": 16, "tolerance": 0.05, "seed": 3}, calls


def test_bake_defaults_are_the_same_call():
    """wavlight.bake and the pixel bake it calls share every default (the spp the pilot chooses)."""
    outer = inspect.signature(wavlight.bake).parameters
    inner = inspect.signature(wavlight.relight.bake.bake).parameters
    for key, p in inner.items():
        if key in outer and p.default is not inspect.Parameter.empty:
            assert outer[key].default == p.default, key
    assert outer["spp"].default is None


def test_docs_tables_are_generated_from_the_records():
    """Every generated table of the docs (docs/update_tables.py) is current: regenerating changes
    nothing."""
    spec = importlib.util.spec_from_file_location("update_tables", ROOT / "docs" / "update_tables.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    for name, found in module.tables().items():
        text = (ROOT / "docs" / name).read_text()
        new, problems = module.updated(text, found, name)
        assert problems == [], problems
        assert new == text, f"docs/{name}: run python docs/update_tables.py"


def test_the_factors_a_bake_varies_are_declared_once():
    """--vary's choices are the bake file's own list of factors (the header's ``vary``,
    checked when a file is read), not a second declaration beside it."""
    from wavlight.relight import store

    assert settings.BAKE["vary"].values is store.VARIES
