"""`wavlight bake` and `wavlight frame`: thin layers over :mod:`wavlight.relight`.

``bake SCENE -o PATH`` precomputes the transfer of the scene's camera and objects;
``frame PATH`` relights it through the frames of the factor it varies
(:func:`wavlight.relight.frames.frames_for`: the lighting, an object's place or the camera): one
frame, a turntable or orbit of frames (``--turntable N`` / ``--orbit N -o DIR``, with its
animations: :mod:`wavlight.animation`), or with ``--spp N`` the unbiased estimate that converges
to the true image. PNG outputs take the display
transform of ``--exposure`` and ``--tonemap`` (:mod:`wavlight.display`), and PNG and EXR outputs
the frame's metadata (:func:`wavlight.imageio.provenance`). Errors are one line and exit 2, as
for ``render``.
"""
from __future__ import annotations

import json
import os
import statistics

import click

from wavlight.relight.settings import BAKE, FRAME

from .common import check_output, fail, flags, given, refuse_inputs
from .progress import progress_bar


@click.command()
@click.argument("scene_file", metavar="SCENE", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, metavar="PATH", help="The bake file to write (any name).")
@flags(BAKE.values())
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object with the choices, sizes and timings.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar and no closing message.")
def bake(scene_file, output, as_json, quiet, **settings):
    """Bake the transfer of SCENE (its camera, objects and materials) into PATH, for relighting."""
    import wavlight

    check_output(output, what="a file")   # before any work; the library checks the room left
    vary = settings["vary"] or BAKE["vary"].default
    try:
        scene = wavlight.load_scene(scene_file)
        refuse_inputs(output, [scene_file, *scene.files])
        if vary == "object" and settings["object"] is None:
            fail("--vary object needs --object NAME (the object that moves)")
        if settings["object"] is not None and vary != "object":
            fail("--object names the object that moves: give it with --vary object")
        if settings["density"] is not None and vary != "view":
            fail("--density sets the surface cache of a view bake: give it with --vary view")
        if scene.environment.is_black:
            fail(f"{scene_file}: [environment]: the environment is black everywhere; nothing to relight")
        with progress_bar("blocks", "rays", quiet) as bar:
            transfer = wavlight.bake(scene, output, progress=bar, **given(settings))
    except wavlight.WavlightError as e:
        fail(e)
    stats = transfer.summary()
    if as_json:
        click.echo(json.dumps(stats))
    elif not quiet:
        click.echo(f"wrote {output}: {stats['width']}x{stats['height']}, {stats['texels']} texels, "
                   f"{stats['file_bytes'] / 1e6:.1f} MB, bake {stats['bake_seconds']:.1f} s "
                   f"({stats['rays_per_second'] / 1e6:.2f} M rays/s)", err=True)


def _look(s) -> dict:
    """The display transform given (``--exposure``, ``--tonemap``), for wavlight.save_image."""
    return given(s, "exposure", "tonemap")


def _check_look(output, s):
    """Before any work: a display transform for a linear output is refused (one line)."""
    from wavlight.errors import WavlightError
    from wavlight.imageio import check_display

    try:
        check_display([output], **_look(s))
    except WavlightError as e:
        fail(e)


def _metadata(transfer, strategy, spp=None, seed=None) -> dict:
    """A frame's metadata: how it was estimated (``relit``: from the bake's transfer, the bake's
    spp and seed; ``unbiased``: its own spp and seed) and the baked scene's content hash."""
    from wavlight.imageio import provenance

    return provenance(strategy, transfer.spp if spp is None else spp,
                      transfer.header.get("seed") if seed is None else seed,
                      (transfer.scene or {}).get("content_hash"))


@click.command()
@click.argument("bake_file", metavar="PATH", type=click.Path(dir_okay=False))
@click.option("-o", "--output", default=None, help="Output image (.exr .hdr .pfm linear; .png sRGB), or with "
              "--turntable or --orbit a folder. Default: the bake file's name with .png.")
@flags(FRAME.values())
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object with timings and choices.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar and no closing message.")
def frame(bake_file, output, as_json, quiet, **settings):
    """Relight the bake file PATH: one frame of its varying factor (the lighting, an object's place
    or the camera), or a turntable or orbit of frames."""
    import time

    import wavlight
    from wavlight import data, display
    from wavlight.imageio import FORMATS
    from wavlight.relight.frames import FRAMES, frames_for

    s = settings
    try:   # the display transform's values (click checks their range, not NaN), before any work
        display.check(**_look(s), where="wavlight frame")
    except wavlight.WavlightError as e:
        fail(e)
    spp = s["spp"]
    try:
        transfer = wavlight.Transfer.load(bake_file)
        kind = FRAMES[transfer.varies]
        kind.refuse_held(bake_file, s)                  # the flags of the factors this bake holds fixed
        count = s[kind.sequence_flag] if kind.sequence_flag else None
        if count is not None and spp is not None:
            fail(f"--{kind.sequence_flag} renders the bake's frames; --spp renders one unbiased frame: give one of "
                 "them")
        unbiased = spp is not None or kind.unbiased
        repeat = s["repeat"] if s["repeat"] is not None else (1 if unbiased else FRAME["repeat"].default)
        env_file = None if s.get("env") is None else data.resolve(s["env"], kind="environment map", download=False)
        inputs = [bake_file, env_file, s["scene"]]
        if count is None:
            if output is None:
                output = os.path.splitext(os.path.basename(bake_file))[0] + ".png"
            check_output(output, FORMATS)
            _check_look(output, s)
            refuse_inputs(output, inputs)
        elif output is None:
            fail(f"--{kind.sequence_flag} writes a folder of frames: give it with -o DIR")
        frames = frames_for(transfer, s["scene"], **given(s, "background"))
        state = frames.state_from(s)                    # checked before anything is written
        meta = (lambda st: _metadata(transfer, "unbiased", st.get("spp"), st.get("seed"))) if unbiased else \
            (lambda st: _metadata(transfer, "relit"))
        times, first = [], None
        if count is None:
            refuse_inputs(output, frames.inputs())
            for i in range(repeat):
                t0 = time.perf_counter()
                if spp is not None:
                    with progress_bar("parts", "rays", quiet or i > 0) as bar:
                        result = frames.converge(state, spp, s["seed"] if s["seed"] is not None else
                                                 FRAME["seed"].default, progress=bar)
                    image, st = result.image, dict(result.stats)
                else:
                    image, st = frames.frame(state)
                times.append(time.perf_counter() - t0)
                first = st if first is None else first
            wavlight.save_image(output, image, **_look(s), metadata=meta(st))
            outputs = [output]
        else:
            names = _frame_folder(output, count, kind.sequence_flag, inputs + frames.inputs())
            with progress_bar("frames", quiet=quiet) as bar:
                for i, ((image, st), name) in enumerate(zip(frames.sequence(frames.turn(state, count)), names)):
                    times.append(st["frame_seconds"])
                    first = st if first is None else first
                    wavlight.save_image(name, image, **_look(s), metadata=meta(st))
                    if bar:
                        bar(i + 1, count)
            outputs = names + _animations(names, output, kind.sequence_flag, quiet)
    except wavlight.WavlightError as e:
        fail(e)
    median = statistics.median(times)
    own = frames.report(state, first if count is not None else st)   # the factor's keys (a view's size)
    stats = {"width": transfer.width, "height": transfer.height, **{k: v for k, v in st.items() if k != "stderr"},
             **own, "vary": frames.factor, "frame": "unbiased" if unbiased else "relit",
             "frame_seconds": round(median, 6), "frames_per_second": round(1.0 / median, 3) if median > 0 else None,
             "first_frame_seconds": round(times[0], 6), "frames": len(times),
             "output": outputs if count is not None else outputs[0]}
    if as_json:
        click.echo(json.dumps(stats, default=_plain))
    elif not quiet:
        what = f"{stats['spp']} spp (unbiased)" if unbiased and stats.get("spp") else \
            (f"{stats['terms']} terms" if stats.get("terms") else "relit")
        click.echo(f"wrote {output}: {stats['width']}x{stats['height']}, {what}, frame {median * 1e3:.1f} ms "
                   f"({stats['frames_per_second']} frames/s)", err=True)


def _plain(value):
    """A JSON value of a numpy scalar or array in a frame's stats."""
    import numpy as np

    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON: {type(value).__name__}")


def _frame_folder(folder, count, stem, inputs):
    """The frames' names in ``folder``, checked before any work with the animations'
    (:func:`wavlight.animation.paths`): a folder (not a file) whose parent exists, that can be
    written (made here once all else passed), no frame or animation that is an input of the run
    or a read-only file."""
    from wavlight import animation

    if os.path.exists(folder) and not os.path.isdir(folder):
        fail(f"{folder}: is a file, not a folder (frames are written into a folder)")
    parent = os.path.dirname(os.path.abspath(folder))
    if not os.path.isdir(parent):
        fail(f"{folder}: no folder {parent}")
    frames = [os.path.join(folder, f"frame-{i:04d}.png") for i in range(count)]
    moving = list(animation.paths(folder, stem).values())
    for name in frames + moving:
        refuse_inputs(name, inputs)
    if not os.path.isdir(folder):
        if not os.access(parent, os.W_OK):
            fail(f"{folder}: cannot make the folder in {parent}")
        try:
            os.mkdir(folder)
        except OSError as e:
            fail(f"{folder}: cannot make the folder ({e.strerror or e})")
    for name in frames + moving:
        check_output(name)
    return frames


def _animations(frames, folder, stem, quiet) -> list:
    """The animations of the frames (:func:`wavlight.animation.write`): the files written; the
    note that names the extra for the MP4 (without PyAV) as one line on stderr."""
    from wavlight import animation

    written, note = animation.write(frames, folder, stem)
    if note and not quiet:
        click.echo(f"note: {note}", err=True)
    return written
