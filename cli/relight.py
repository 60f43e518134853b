"""`wavlight bake` and `wavlight frame`: thin layers over :mod:`wavlight.relight`.

``bake SCENE -o PATH`` precomputes the transfer of the scene's camera and objects;
``frame PATH`` relights it: one frame under another map, rotation or scale, a turntable of
frames (``--turntable N -o DIR``), or with ``--spp N`` the unbiased estimate that converges to
the true image. Errors are one line and exit 2, as for ``render``.
"""
from __future__ import annotations

import json
import os
import statistics
import sys

import click

from .common import check_output, fail, refuse_inputs
from .progress import ProgressBar


@click.command()
@click.argument("scene_file", metavar="SCENE", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, metavar="PATH", help="The bake file to write (any name).")
@click.option("--width", type=int, default=None, help="Image width (default: the scene's).")
@click.option("--height", type=int, default=None, help="Image height (default: the scene's).")
@click.option("--spp", type=click.IntRange(1, 64), default=None,
              help="Camera samples per pixel, stratified over the pixel (they share each texel's shadow ray). "
                   "Default: the fewest of 16, 32, 64 the tolerance needs, from two pilot bakes that measure the noise.")
@click.option("--levels", type=click.IntRange(2, 8), default=None,
              help="Texels: 2^n x 2^n on the lat-long square. Default: the fewest that meet the tolerance, "
                   "from a pilot bake.")
@click.option("--tolerance", type=click.FloatRange(1e-6, 1.0), default=0.02, show_default=True,
              help="Relative L2 error of frames, measured on held-out rotations: shared by the bake's noise, "
                   "the texels' resolution, the terms and the compression.")
@click.option("--points", type=click.Choice(["1", "4", "16"]), default=None,
              help="Points per texel where the BRDF is evaluated (1, 2 x 2 or 4 x 4 strata). Default: the fewest "
                   "that put 16 point spacings across the narrowest lobe.")
@click.option("--bits", type=click.Choice(["8", "16"]), default="8", show_default=True,
              help="Quantization of the stored coefficients.")
@click.option("--terms", type=click.IntRange(1, 1 << 22), default=None,
              help="The lighting terms K a frame keeps by default. Default: the fewest that meet the tolerance.")
@click.option("--priority", type=click.Choice(["transfer", "area", "magnitude"]), default=None,
              help="How frames rank the lighting's terms. Default: the better of transfer and area on the pilot.")
@click.option("--seed", type=click.IntRange(0, 2 ** 62), default=0, show_default=True, help="Random seed.")
@click.option("--vary", type=click.Choice(["lighting", "object", "view"]), default="lighting", show_default=True,
              help="The factor frames vary: the lighting (map, rotation, scale), one object's place, or the camera "
                   "(view: T1 = L V cos on a surface cache; --width, --height and --spp do not apply).")
@click.option("--density", type=click.FloatRange(1e-9, 1e18, min_open=True), default=None,
              help="--vary view: surface cache points per unit area (default: 65536 over the scene's area).")
@click.option("--object", "moving", default=None, metavar="NAME",
              help="--vary object: the object that moves (its name, or its index among [[objects]]).")
@click.option("--static-spp", type=click.IntRange(2, 1 << 20), default=256, show_default=True,
              help="--vary object: samples per pixel of the scene without the object, converged at the bake.")
@click.option("--dask", "dask_address", metavar="tcp://HOST:PORT", default=None,
              help="Bake the blocks on this dask.distributed scheduler (its workers read the scene file at the "
                   "same path); the file is identical to a local bake's.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object with the choices, sizes and timings.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar and no closing message.")
def bake(scene_file, output, width, height, spp, levels, tolerance, points, bits, terms, priority, seed, vary, density,
         moving, static_spp, dask_address, as_json, quiet):
    """Bake the transfer of SCENE (its camera, objects and materials) into PATH, for relighting."""
    import wavlight

    if os.path.isdir(output):
        fail(f"{output}: is a folder, not a file")
    folder = os.path.dirname(os.path.abspath(output))
    if not os.path.isdir(folder):
        fail(f"{output}: no folder {folder}")
    try:
        scene = wavlight.load_scene(scene_file)
        refuse_inputs(output, [scene_file, *scene.files])
        if vary == "object" and moving is None:
            fail("--vary object needs --object NAME (the object that moves)")
        if moving is not None and vary != "object":
            fail("--object names the object that moves: give it with --vary object")
        if density is not None and vary != "view":
            fail("--density sets the surface cache of a view bake: give it with --vary view")
        if scene.environment.is_black:
            fail(f"{scene_file}: [environment]: the environment is black everywhere; nothing to relight")
        bar = None if quiet or not sys.stderr.isatty() else ProgressBar(sys.stderr, unit="rays")
        transfer = wavlight.bake(scene, output, width=width, height=height, spp=spp, levels=levels,
                                 tolerance=tolerance, bits=int(bits), terms=terms, priority=priority, seed=seed,
                                 progress=bar, dask_address=dask_address,
                                 points=None if points is None else int(points), vary=vary, object=moving,
                                 static_spp=static_spp, density=density)
        if bar:
            bar.close()
    except wavlight.WavlightError as e:
        fail(e)
    stats = transfer.summary()
    if as_json:
        click.echo(json.dumps(stats))
    elif not quiet:
        click.echo(f"wrote {output}: {stats['width']}x{stats['height']}, {stats['texels']} texels, "
                   f"{stats['file_bytes'] / 1e6:.1f} MB, bake {stats['bake_seconds']:.1f} s "
                   f"({stats['rays_per_second'] / 1e6:.2f} M rays/s)", err=True)


@click.command()
@click.argument("bake_file", metavar="PATH", type=click.Path(dir_okay=False))
@click.option("--env", "env_file", default=None, metavar="FILE", help="Another environment map (default: the baked one).")
@click.option("--rotate-y", type=float, default=None,
              help="Rotation of the map about +Y, degrees, absolute as the scene's rotate_y (default: the scene's).")
@click.option("--scale", type=click.FloatRange(0.0, 1e30), default=1.0, show_default=True, help="Radiance scale.")
@click.option("--terms", type=click.IntRange(1, 1 << 22), default=None,
              help="Lighting terms K kept (default: the bake's choice).")
@click.option("--priority", type=click.Choice(["transfer", "area", "magnitude"]), default=None,
              help="How the K terms are chosen (default: the bake's).")
@click.option("-o", "--output", default=None, help="Output image (.exr .hdr .pfm linear; .png sRGB), or with "
              "--turntable a folder. Default: the bake file's name with .png.")
@click.option("--turntable", type=click.IntRange(1, 3600), default=None, metavar="N",
              help="N frames of a full turn about +Y into the folder -o DIR (PNG; and an animated GIF).")
@click.option("--repeat", type=click.IntRange(1, 1000), default=5, show_default=True,
              help="Frames computed to time one (the median is reported).")
@click.option("--spp", type=click.IntRange(1, 1 << 16), default=None,
              help="The unbiased frame instead: N camera samples per pixel, directions from the product of "
                   "transfer and lighting and from the BSDF, true shadow rays (reloads the baked scene).")
@click.option("--seed", type=click.IntRange(0, 2 ** 62), default=0, show_default=True, help="Random seed (--spp).")
@click.option("--translate", type=float, nargs=3, default=None, metavar="X Y Z",
              help="A bake with --vary object: the object's translation (absolute, replacing its own).")
@click.option("--rotate", type=float, nargs=4, default=None, metavar="AX AY AZ DEG",
              help="A bake with --vary object: the object's rotation, axis and degrees (absolute).")
@click.option("--scene", "scene_file", default=None, metavar="FILE",
              help="The scene the bake was made from, where it is not at the path the bake recorded (--spp).")
@click.option("--eye", type=float, nargs=3, default=None, metavar="X Y Z",
              help="A bake with --vary view: the camera's position (default: the scene's).")
@click.option("--target", type=float, nargs=3, default=None, metavar="X Y Z",
              help="A bake with --vary view: the point the camera looks at (default: the scene's).")
@click.option("--fov", type=float, default=None, metavar="DEG",
              help="A bake with --vary view: the vertical field of view, degrees (default: the scene's).")
@click.option("--width", type=click.IntRange(1, 16384), default=None,
              help="A bake with --vary view: image width (default: the scene's).")
@click.option("--height", type=click.IntRange(1, 16384), default=None,
              help="A bake with --vary view: image height (default: the scene's).")
@click.option("--orbit", type=click.IntRange(1, 3600), default=None, metavar="N",
              help="A bake with --vary view: N frames of an orbit of the eye about the target (about +Y) into "
                   "the folder -o DIR (PNG; and an animated GIF).")
@click.option("--refine", type=click.FloatRange(1e-4, 100.0), default=None,
              help="A bake with --vary view: a BRDF node's angular radius at most REFINE times its distance from "
                   "the lobe plus the lobe's width, divided by g >= sqrt(share / MASS) (a power of two) where the "
                   "node holds more than MASS of the transfer (smaller: more nodes, closer to the texels' sum). "
                   "Default 0.6.")
@click.option("--mass", type=click.FloatRange(0.0, 1.0), default=None,
              help="A bake with --vary view: a node holding more than this share of the transfer's mass (a sun) is "
                   "refined further (0: by the lobe alone). Default 0.003.")
@click.option("--mode", type=click.Choice(["point", "pixel"]), default=None,
              help="A bake with --vary view: a product per cache point, blended per pixel (fast: the viewer's), or "
                   "per pixel of its points' blended transfer with the pixel's face normal and view (closer to mis; "
                   "slower). Default pixel.")
@click.option("--supersample", type=click.IntRange(1, 16), default=None, metavar="S",
              help="A bake with --vary view: S x S rays per pixel, averaged (a mesh's facets can be smaller than a "
                   "pixel). Default 4 in --mode pixel, 1 in --mode point (the viewer's frame).")
@click.option("--tau", type=click.FloatRange(0.0, 100.0), default=None,
              help="A bake with --vary view, --mode pixel: the tolerance of the correction of the baked cosine to "
                   "the face's (0: none). Default 0.1.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object with timings and choices.")
@click.option("--quiet", "-q", is_flag=True, help="No closing message.")
def frame(bake_file, env_file, rotate_y, scale, terms, priority, output, turntable, repeat, spp, seed, translate,
          rotate, scene_file, eye, target, fov, width, height, orbit, refine, mass, mode, supersample, tau, as_json,
          quiet):
    """Relight the bake file PATH: one frame under new lighting (or a turntable of frames)."""
    import math


    import wavlight
    from wavlight.imageio import FORMATS
    from wavlight.relight.lighting import turntable as turntable_rotations

    if rotate_y is not None and not math.isfinite(rotate_y):
        fail(f"--rotate-y must be a finite number of degrees, got {rotate_y}")
    try:
        transfer = wavlight.Transfer.load(bake_file)
        varies = transfer.header.get("vary", "lighting")
        camera = {"--eye": eye, "--target": target, "--fov": fov, "--width": width, "--height": height,
                  "--orbit": orbit, "--refine": refine, "--mass": mass, "--mode": mode, "--supersample": supersample,
                  "--tau": tau}
        if varies == "view":
            approximate = {"refine": refine, "mass": mass, "mode": mode, "supersample": supersample, "tau": tau}
            return _view_frame(transfer, bake_file, output, eye, target, fov, width, height, orbit, spp, seed,
                               repeat, scene_file, as_json, quiet, approximate,
                               {"--env": env_file, "--rotate-y": rotate_y, "--scale": scale if scale != 1.0 else None,
                                "--terms": terms, "--priority": priority, "--turntable": turntable,
                                "--translate": translate, "--rotate": rotate})
        for flag, value in camera.items():
            if value is not None:
                factor = "lighting" if varies == "lighting" else "object"
                fail(f"{bake_file}: this bake varies the {factor} (its camera is fixed); {flag} is for a moving camera "
                     "(bake with --vary view)")
        if varies == "object":
            return _object_frame(transfer, bake_file, output, translate, rotate, spp, seed, scene_file, as_json, quiet,
                                 {"--env": env_file, "--rotate-y": rotate_y, "--scale": scale if scale != 1.0 else None,
                                  "--terms": terms, "--priority": priority, "--turntable": turntable})
        for flag, value in (("--translate", translate), ("--rotate", rotate)):
            if value is not None:
                fail(f"{bake_file}: this bake varies the lighting; {flag} moves an object (bake with --vary object)")
        env = None
        if env_file is not None:
            env = transfer.environment(env_file, scale)
            scale_used = 1.0
        else:
            scale_used = scale
        if (env if env is not None else transfer.environment(None, scale)).is_black:
            scaled = f" times --scale {scale:g}" if scale != 1.0 else ""
            fail(f"{env_file or bake_file}: the environment{scaled} is black everywhere; the frame would be black")
        if turntable is None:
            if output is None:
                output = os.path.splitext(os.path.basename(bake_file))[0] + ".png"
            check_output(output, FORMATS)
            refuse_inputs(output, [bake_file, env_file])
            times = []
            if spp is not None:
                from wavlight.relight.converge import converge

                bar = None if quiet or not sys.stderr.isatty() else ProgressBar(sys.stderr, unit="rays")
                result = converge(transfer, scene_file, env, rotate_y, scale_used, spp=spp, seed=seed, progress=bar)
                if bar:
                    bar.close()
                image, st = result.image, {"frame_seconds": result.stats["render_seconds"], "terms": None,
                                           "entries_read": 0}
                times.append(st["frame_seconds"])
            else:
                for _ in range(repeat):
                    image, st = transfer.frame_timed(env, rotate_y, scale_used, terms, priority)
                    times.append(st["frame_seconds"])
                rotation = st["rotate_y"]
            wavlight.save_image(output, image)
            outputs = [output]
        else:
            if output is None:
                fail("--turntable writes a folder of frames: give it with -o DIR")
            os.makedirs(output, exist_ok=True)
            turns = turntable_rotations(transfer.scene_rotate_y if rotate_y is None else rotate_y, turntable)
            rotation = turns[0]
            times, outputs, frames = [], [], []
            for i, turn in enumerate(turns):
                image, st = transfer.frame_timed(env, turn, scale_used, terms, priority)
                times.append(st["frame_seconds"])
                name = os.path.join(output, f"frame-{i:04d}.png")
                wavlight.save_image(name, image)
                outputs.append(name)
                frames.append(name)
            gif = _animated_gif(frames, os.path.join(output, "turntable.gif"))
            if gif:
                outputs.append(gif)
    except wavlight.WavlightError as e:
        fail(e)
    median = statistics.median(times)
    if spp is not None:
        _report_unbiased({"spp": spp, "seed": seed, "frame_seconds": round(median, 4), **result.stats,
                          "output": outputs[0]}, (transfer.width, transfer.height), as_json, quiet)
        return
    stats = {"frame_seconds": round(median, 6), "frames_per_second": round(1.0 / median, 2) if median > 0 else None,
             "terms": st["terms"], "entries_read": st["entries_read"], "width": transfer.width,
             "height": transfer.height, "texels": f"{1 << transfer.n_levels}x{1 << transfer.n_levels}",
             "priority": priority or transfer.priority, "frames": len(times), "rotate_y": rotation,
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


def _animated_gif(frames, path):
    """An animated GIF of the PNG frames where Pillow is installed (it is a dependency); None if not."""
    try:
        from PIL import Image
    except ImportError:
        return None
    images = [Image.open(f).convert("RGB") for f in frames]
    tmp = path + ".part"
    images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=40, loop=0)
    os.replace(tmp, path)
    return path


def _object_frame(transfer, bake_file, output, translate, rotate, spp, seed, scene_file, as_json, quiet, held):
    """A frame of a bake that varies one object: the object at --translate / --rotate."""
    import math

    import wavlight
    from wavlight.imageio import FORMATS
    from wavlight.relight.moving import MovingObject
    from wavlight.scene import MAX_COORDINATE

    for flag, value in held.items():
        if value is not None:
            fail(f"{bake_file}: this bake varies an object (its lighting is fixed); {flag} does not apply")
    if translate is not None and not all(math.isfinite(x) and abs(x) <= MAX_COORDINATE for x in translate):
        fail(f"--translate must be three finite numbers within the ray tracer's range (|x| <= {MAX_COORDINATE:g}), "
             f"got {' '.join(str(x) for x in translate)}")
    if output is None:
        output = os.path.splitext(os.path.basename(bake_file))[0] + ".png"
    check_output(output, FORMATS)
    refuse_inputs(output, [bake_file, scene_file])
    mover = MovingObject(transfer, scene_file)
    refuse_inputs(output, [mover.scene.path, *mover.scene.files])
    result = mover.frame(translate, rotate, spp=4 if spp is None else spp, seed=seed)
    wavlight.save_image(output, result.image)
    stats = {"frame_seconds": result.stats["render_seconds"],
             "frames_per_second": round(1.0 / result.stats["render_seconds"], 3), **result.stats, "output": output}
    if as_json:
        click.echo(json.dumps(stats))
    elif not quiet:
        click.echo(f"wrote {output}: {transfer.width}x{transfer.height}, {stats['spp']} spp, object at "
                   f"{stats['translate']}, {stats['frame_seconds']:.2f} s", err=True)


def _view_frame(transfer, bake_file, output, eye, target, fov, width, height, orbit, spp, seed, repeat,
                scene_file, as_json, quiet, approximate, held):
    """A frame of a bake that varies the view: the camera at --eye looking at --target (or an
    --orbit of frames, or with --spp the unbiased frame); ``approximate`` the approximate frame's
    options as given (None: the written frame's defaults, view.STILL)."""
    import math

    import wavlight
    from wavlight.imageio import FORMATS
    from wavlight.relight.view import STILL, ViewFrames, orbit_eyes
    from wavlight.scene import MAX_COORDINATE

    for flag, value in held.items():
        if value is not None:
            fail(f"{bake_file}: this bake varies the view (its lighting and objects are fixed); {flag} does not apply")
    for flag, value in (("--eye", eye), ("--target", target)):
        if value is not None and not all(math.isfinite(x) and abs(x) <= MAX_COORDINATE for x in value):
            fail(f"{flag} must be three finite numbers within the ray tracer's range (|x| <= {MAX_COORDINATE:g}), "
                 f"got {' '.join(str(x) for x in value)}")
    if fov is not None and not (math.isfinite(fov) and 0.0 < fov < 180.0):
        fail(f"--fov must be a number of degrees in (0, 180), got {fov}")
    if spp is not None:
        for key, value in approximate.items():
            if value is not None:
                fail(f"--{key} sets the approximate frame; --spp renders the unbiased one: give one of them")
    opts = {k: STILL[k] if v is None else v for k, v in approximate.items()}
    if approximate["supersample"] is None and opts["mode"] == "point":
        opts["supersample"] = 1   # more rays do not sharpen point mode's blend (docs/decisions/view-point-mode.md)
    if approximate["tau"] is not None and opts["mode"] != "pixel":
        fail("--tau corrects the cosine of --mode pixel: give it with --mode pixel")
    if orbit is not None and spp is not None:
        fail("--orbit renders approximate frames; --spp renders one unbiased frame: give one of them")
    if orbit is None:
        if output is None:
            output = os.path.splitext(os.path.basename(bake_file))[0] + ".png"
        check_output(output, FORMATS)
        refuse_inputs(output, [bake_file, scene_file])
    else:
        if output is None:
            fail("--orbit writes a folder of frames: give it with -o DIR")
        if os.path.exists(output) and not os.path.isdir(output):
            fail(f"{output}: is a file, not a folder (--orbit writes a folder of frames)")
        if not os.path.isdir(os.path.dirname(os.path.abspath(output))):
            fail(f"{output}: no folder {os.path.dirname(os.path.abspath(output))}")
    frames = ViewFrames(transfer, scene_file)
    if orbit is None:
        refuse_inputs(output, [frames.scene.path, *frames.scene.files])
    cam = frames.camera(eye, target, fov)          # checked before anything is written
    size = frames._size(width, height)
    view = {"width": size[0], "height": size[1], "eye": cam.eye.tolist(), "target": cam.target.tolist(),
            "fov": cam.fov_y}
    if spp is not None:
        bar = None if quiet or not sys.stderr.isatty() else ProgressBar(sys.stderr, unit="rays")
        result = frames.converge(cam.eye, cam.target, cam.fov_y, *size, spp=spp, seed=seed, progress=bar)
        if bar:
            bar.close()
        wavlight.save_image(output, result.image)
        _report_unbiased({"frame_seconds": result.stats["render_seconds"], **result.stats, "output": output}, size,
                         as_json, quiet)
        return
    times, outputs = [], []
    if orbit is None:
        for _ in range(repeat):
            image, st = frames.frame(cam.eye, cam.target, cam.fov_y, *size, **opts)
            times.append(st["frame_seconds"])
        wavlight.save_image(output, image)
        outputs.append(output)
    else:
        os.makedirs(output, exist_ok=True)
        names = []
        for i, e in enumerate(orbit_eyes(cam.eye, cam.target, orbit)):
            image, st = frames.frame(e, cam.target, cam.fov_y, *size, **opts)
            times.append(st["frame_seconds"])
            name = os.path.join(output, f"frame-{i:04d}.png")
            wavlight.save_image(name, image)
            names.append(name)
        outputs = names + [g for g in [_animated_gif(names, os.path.join(output, "orbit.gif"))] if g]
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
