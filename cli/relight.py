"""`wavlight bake` and `wavlight frame`: thin layers over :mod:`wavlight.relight`.

``bake SCENE -o PATH`` precomputes the transfer of the scene's camera and objects;
``frame PATH`` relights it: one frame under another map, rotation or scale, a turntable of
frames (``--turntable N -o DIR``, with its animations: :mod:`wavlight.animation`), or with
``--spp N`` the unbiased estimate that converges to the true image. PNG outputs take the display
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


#: the flags of a frame that set the lighting, a moved object, and the camera of a view bake
LIGHTING_FLAGS = ("env", "rotate_y", "scale", "terms", "priority", "turntable", "background")
OBJECT_FLAGS = ("translate", "rotate")
VIEW_FLAGS = ("eye", "target", "fov", "width", "height", "orbit", "refine", "mass", "mode", "supersample", "tau")


@click.command()
@click.argument("bake_file", metavar="PATH", type=click.Path(dir_okay=False))
@click.option("-o", "--output", default=None, help="Output image (.exr .hdr .pfm linear; .png sRGB), or with "
              "--turntable or --orbit a folder. Default: the bake file's name with .png.")
@flags(FRAME.values())
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object with timings and choices.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar and no closing message.")
def frame(bake_file, output, as_json, quiet, **settings):
    """Relight the bake file PATH: one frame under new lighting (or a turntable of frames)."""
    import math

    import wavlight
    from wavlight import data, display
    from wavlight.imageio import FORMATS
    from wavlight.relight.lighting import turntable as turntable_rotations

    s = settings
    try:   # the display transform's values (click checks their range, not NaN), before any work
        display.check(**_look(s), where="wavlight frame")
    except wavlight.WavlightError as e:
        fail(e)
    rotate_y, spp, turntable = s["rotate_y"], s["spp"], s["turntable"]
    repeat = FRAME["repeat"].default if s["repeat"] is None else s["repeat"]
    if rotate_y is not None and not math.isfinite(rotate_y):
        fail(f"--rotate-y must be a finite number of degrees, got {rotate_y}")
    held = lambda keys: {FRAME[k].flag: s[k] for k in keys}   # noqa: E731  (flags of a fixed factor)
    try:
        transfer = wavlight.Transfer.load(bake_file)
        varies = transfer.header.get("vary", "lighting")
        if varies == "view":
            return _view_frame(transfer, bake_file, output, s, repeat, as_json, quiet,
                               held(tuple(k for k in LIGHTING_FLAGS if k != "background") + OBJECT_FLAGS))
        for flag_name, value in held(VIEW_FLAGS).items():
            if value is not None:
                factor = "lighting" if varies == "lighting" else "object"
                fail(f"{bake_file}: this bake varies the {factor} (its camera is fixed); {flag_name} is for a moving "
                     "camera (bake with --vary view)")
        if varies == "object":
            return _object_frame(transfer, bake_file, output, s, as_json, quiet, held(LIGHTING_FLAGS))
        for flag_name, value in held(OBJECT_FLAGS).items():
            if value is not None:
                fail(f"{bake_file}: this bake varies the lighting; {flag_name} moves an object "
                     "(bake with --vary object)")
        lit = given(s, "rotate_y", "scale", "terms", "priority", "background")   # the frame's lighting, as given
        env_file = None if s["env"] is None else data.resolve(s["env"], kind="environment map", download=False)
        env = None
        if s["env"] is not None:
            env = transfer.environment(s["env"], **given(s, "scale"))
            lit.pop("scale", None)   # in env already
        scale = FRAME["scale"].default if s["scale"] is None else s["scale"]
        if (env if env is not None else transfer.environment(None, scale)).is_black:
            scaled = f" times --scale {scale:g}" if scale != 1.0 else ""
            fail(f"{s['env'] or bake_file}: the environment{scaled} is black everywhere; the frame would be black")
        if turntable is None:
            if output is None:
                output = os.path.splitext(os.path.basename(bake_file))[0] + ".png"
            check_output(output, FORMATS)
            _check_look(output, s)
            refuse_inputs(output, [bake_file, env_file])
            times = []
            if spp is not None:
                from wavlight.relight.converge import converge

                with progress_bar("parts", "rays", quiet) as bar:
                    result = converge(transfer, s["scene"], env, spp=spp, progress=bar,
                                      **given(s, "rotate_y", "seed"), **given(lit, "scale", "background"))
                image, st = result.image, {"frame_seconds": result.stats["frame_seconds"], "terms": None,
                                           "entries_read": 0}
                times.append(st["frame_seconds"])
            else:
                for _ in range(repeat):
                    image, st = transfer.frame_timed(env, **lit)
                    times.append(st["frame_seconds"])
                rotation = st["rotate_y"]
            meta = (_metadata(transfer, "unbiased", spp, result.stats["seed"]) if spp is not None
                    else _metadata(transfer, "relit"))
            wavlight.save_image(output, image, **_look(s), metadata=meta)
            outputs = [output]
        else:
            if output is None:
                fail("--turntable writes a folder of frames: give it with -o DIR")
            frames = _frame_folder(output, turntable, "turntable", [bake_file, env_file])
            turns = turntable_rotations(transfer.scene_rotate_y if rotate_y is None else rotate_y, turntable)
            rotation = turns[0]
            lit.pop("rotate_y", None)
            times = []
            with progress_bar("frames", quiet=quiet) as bar:
                for i, (turn, name) in enumerate(zip(turns, frames)):
                    image, st = transfer.frame_timed(env, turn, **lit)
                    times.append(st["frame_seconds"])
                    wavlight.save_image(name, image, **_look(s), metadata=_metadata(transfer, "relit"))
                    if bar:
                        bar(i + 1, turntable)
            outputs = frames + _animations(frames, output, "turntable", quiet)
    except wavlight.WavlightError as e:
        fail(e)
    median = statistics.median(times)
    if spp is not None:
        _report_unbiased({"spp": spp, "seed": result.stats["seed"], "frame_seconds": round(median, 4),
                          **result.stats, "output": outputs[0]}, (transfer.width, transfer.height), as_json, quiet)
        return
    stats = {"frame_seconds": round(median, 6), "frames_per_second": round(1.0 / median, 2) if median > 0 else None,
             "terms": st["terms"], "entries_read": st["entries_read"], "width": transfer.width,
             "height": transfer.height, "texels": f"{1 << transfer.n_levels}x{1 << transfer.n_levels}",
             "priority": s["priority"] or transfer.priority, "frames": len(times), "rotate_y": rotation,
             "background": s["background"] or FRAME["background"].default,
             "memory_bytes_per_frame": int(st["entries_read"] * (transfer.block ** 2 * transfer.bits // 8 + 20)),
             "measured": transfer.measured, "output": outputs if turntable else outputs[0]}
    if as_json:
        click.echo(json.dumps(stats))
    elif not quiet:
        click.echo(f"wrote {stats['output'] if not turntable else output}: {transfer.width}x{transfer.height}, "
                   f"{stats['terms']} terms, frame {median * 1e3:.1f} ms ({stats['frames_per_second']} frames/s)",
                   err=True)


def _report_unbiased(stats: dict, size, as_json: bool, quiet: bool):
    """An unbiased frame's report: one JSON object, or a line on stderr naming the output."""
    if as_json:
        click.echo(json.dumps(stats))
    elif not quiet:
        click.echo(f"wrote {stats['output']}: {size[0]}x{size[1]}, {stats['spp']} spp (unbiased), "
                   f"{stats['frame_seconds']:.2f} s", err=True)


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


def _object_frame(transfer, bake_file, output, s, as_json, quiet, held):
    """A frame of a bake that varies one object: the object at --translate / --rotate."""
    import math

    import wavlight
    from wavlight.imageio import FORMATS
    from wavlight.relight.moving import MovingObject
    from wavlight.scene import MAX_COORDINATE

    for flag_name, value in held.items():
        if value is not None:
            fail(f"{bake_file}: this bake varies an object (its lighting is fixed); {flag_name} does not apply")
    translate = s["translate"]
    if translate is not None and not all(math.isfinite(x) and abs(x) <= MAX_COORDINATE for x in translate):
        fail(f"--translate must be three finite numbers within the ray tracer's range (|x| <= {MAX_COORDINATE:g}), "
             f"got {' '.join(str(x) for x in translate)}")
    if output is None:
        output = os.path.splitext(os.path.basename(bake_file))[0] + ".png"
    check_output(output, FORMATS)
    _check_look(output, s)
    refuse_inputs(output, [bake_file, s["scene"]])
    mover = MovingObject(transfer, s["scene"])
    refuse_inputs(output, [mover.scene.path, *mover.scene.files])
    result = mover.frame(s["translate"], s["rotate"], **given(s, "spp", "seed"))
    wavlight.save_image(output, result.image, **_look(s),
                        metadata=_metadata(transfer, "unbiased", result.stats.get("spp"), result.stats.get("seed")))
    stats = {"frame_seconds": result.stats["render_seconds"],
             "frames_per_second": round(1.0 / result.stats["render_seconds"], 3), **result.stats, "output": output}
    if as_json:
        click.echo(json.dumps(stats))
    elif not quiet:
        click.echo(f"wrote {output}: {transfer.width}x{transfer.height}, {stats['spp']} spp, object at "
                   f"{stats['translate']}, {stats['frame_seconds']:.2f} s", err=True)


#: the approximate frame's settings of a view bake (view.still_settings)
APPROXIMATE = ("refine", "mass", "mode", "supersample", "tau")


def _view_frame(transfer, bake_file, output, s, repeat, as_json, quiet, held):
    """A frame of a bake that varies the view: the camera at --eye looking at --target (or an
    --orbit of frames, or with --spp the unbiased frame), the approximate frame's settings as
    given, the others a written frame's (view.still_settings)."""
    import math

    import wavlight
    from wavlight.imageio import FORMATS
    from wavlight.relight.view import ViewFrames, orbit_eyes, still_settings
    from wavlight.scene import MAX_COORDINATE

    eye, target, fov, orbit, spp = s["eye"], s["target"], s["fov"], s["orbit"], s["spp"]
    for flag_name, value in held.items():
        if value is not None:
            fail(f"{bake_file}: this bake varies the view (its lighting and objects are fixed); {flag_name} does not "
                 "apply")
    for key in ("eye", "target"):
        if s[key] is not None and not all(math.isfinite(x) and abs(x) <= MAX_COORDINATE for x in s[key]):
            fail(f"{FRAME[key].flag} must be three finite numbers within the ray tracer's range (|x| <= "
                 f"{MAX_COORDINATE:g}), got {' '.join(str(x) for x in s[key])}")
    why = None if fov is None else FRAME["fov"].problem(fov)
    if why:
        fail(f"--fov {why}")
    approximate = given(s, *APPROXIMATE)
    if spp is not None and approximate:
        fail(f"{FRAME[next(iter(approximate))].flag} sets the approximate frame; --spp renders the unbiased one: "
             "give one of them")
    opts = still_settings(**approximate)
    if s["tau"] is not None and opts["mode"] != "pixel":
        fail("--tau corrects the cosine of --mode pixel: give it with --mode pixel")
    if orbit is not None and spp is not None:
        fail("--orbit renders approximate frames; --spp renders one unbiased frame: give one of them")
    if orbit is None:
        if output is None:
            output = os.path.splitext(os.path.basename(bake_file))[0] + ".png"
        check_output(output, FORMATS)
        _check_look(output, s)
        refuse_inputs(output, [bake_file, s["scene"]])
    else:
        if output is None:
            fail("--orbit writes a folder of frames: give it with -o DIR")
    frames = ViewFrames(transfer, s["scene"], **given(s, "background"))
    if orbit is None:
        refuse_inputs(output, [frames.scene.path, *frames.scene.files])
    else:
        names = _frame_folder(output, orbit, "orbit", [bake_file, s["scene"], frames.scene.path, *frames.scene.files])
    cam = frames.camera(eye, target, fov)          # checked before anything is written
    size = frames.size(s["width"], s["height"])
    view = {"width": size[0], "height": size[1], "eye": cam.eye.tolist(), "target": cam.target.tolist(),
            "fov": cam.fov_y}
    if spp is not None:
        with progress_bar("parts", "rays", quiet) as bar:
            result = frames.converge(cam.eye, cam.target, cam.fov_y, *size, spp=spp, progress=bar, **given(s, "seed"))
        wavlight.save_image(output, result.image, **_look(s),
                            metadata=_metadata(transfer, "unbiased", spp, result.stats.get("seed")))
        _report_unbiased({"frame_seconds": result.stats["render_seconds"], **result.stats, "output": output}, size,
                         as_json, quiet)
        return
    times, outputs = [], []
    if orbit is None:
        for _ in range(repeat):
            image, st = frames.frame(cam.eye, cam.target, cam.fov_y, *size, **opts)
            times.append(st["frame_seconds"])
        wavlight.save_image(output, image, **_look(s), metadata=_metadata(transfer, "relit"))
        outputs.append(output)
    else:
        with progress_bar("frames", quiet=quiet) as bar:
            for i, (e, name) in enumerate(zip(orbit_eyes(cam.eye, cam.target, orbit), names)):
                image, st = frames.frame(e, cam.target, cam.fov_y, *size, **opts)
                times.append(st["frame_seconds"])
                wavlight.save_image(name, image, **_look(s), metadata=_metadata(transfer, "relit"))
                if bar:
                    bar(i + 1, orbit)
        outputs = names + _animations(names, output, "orbit", quiet)
    median = statistics.median(times)
    stats = {"frame_seconds": round(median, 6), "frames_per_second": round(1.0 / median, 2) if median > 0 else None,
             "frames": len(times), **view, **opts, "tau": opts["tau"] if opts["mode"] == "pixel" else None,
             "texels": f"{1 << transfer.n_levels}x{1 << transfer.n_levels}",
             "timings": {k: round(v, 6) for k, v in st.items() if k.endswith("_seconds")},
             "cache_points_shaded": st["cache_points_shaded"], "nodes_per_point": st["nodes_per_point"],
             "model": transfer.header.get("model"), "output": outputs if orbit else outputs[0]}
    if as_json:
        click.echo(json.dumps(stats))
    elif not quiet:
        click.echo(f"wrote {output}: {size[0]}x{size[1]}, frame {median * 1e3:.1f} ms "
                   f"({stats['frames_per_second']} frames/s)", err=True)
