"""The `wavlight` command line: a thin layer over the library.

Errors in input (scene, files, options) print one line and exit with code 2;
warnings print one line each to stderr. Input repaired rather than refused (NaN, Inf or
negative texels set to 0, degenerate triangles removed: wavlight.SanitisedInputWarning)
lets the command finish and write its output, then exit with code 3, so that scripts
notice; other warnings (an LDR map, albedo above 1) leave the exit code 0.
"""
from __future__ import annotations

import json
import logging
import os
import signal
import sys
import warnings

import click

from wavlight.display import DISPLAY
from wavlight.options import BACKGROUND, HEIGHT, SEED, SPP, WIDTH
from wavlight.strategies import APPLIES, OPTIONS, STRATEGIES

from .common import check_output, fail, flag, flags, given, one_line, refuse_inputs
from .progress import progress_bar


#: set when a SanitisedInputWarning was shown during this invocation (the exit code becomes 3)
_sanitised = False


def _warn_line(message, category, filename, lineno, file=None, line=None):
    global _sanitised
    from wavlight.errors import SanitisedInputWarning

    if issubclass(category, SanitisedInputWarning):
        _sanitised = True
    click.echo(f"warning: {one_line(message)}", err=True)


class _NoteLine(logging.Handler):
    """The library's INFO log lines (``wavlight.cl``: "compiling OpenCL kernels ...") as one
    ``note:`` line each on stderr."""

    def emit(self, record):
        click.echo(f"note: {one_line(record.getMessage())}", err=True)


def _show_library_notes():
    """On a terminal only, as the progress bar: scripts reading stderr see errors and warnings."""
    logger = logging.getLogger("wavlight.cl")
    if sys.stderr.isatty() and not any(isinstance(h, _NoteLine) for h in logger.handlers):
        logger.addHandler(_NoteLine(logging.INFO))
        logger.setLevel(logging.INFO)


def _show_usage_error(self, file=None):
    """Bad options and arguments in one line too, instead of click's usage block."""
    hint = f" (see '{self.ctx.command_path} --help')" if self.ctx is not None else ""
    click.echo(f"Error: {one_line(self.format_message())}{hint}", file=file, err=True)


click.ClickException.exit_code = 2
click.UsageError.show = _show_usage_error

#: exit codes of a command stopped by a signal: 128 + its number, the shells' convention
INTERRUPTED_EXIT_CODE = 128 + signal.SIGINT


class _Commands(click.Group):
    """Every command under SIGINT and SIGTERM: the work stops, the files being written and the
    scratch files are removed on the way out (wavlight.atomic), one line says so, and the exit
    code is 130 (SIGINT) or 143 (SIGTERM). Files already written are complete."""

    def invoke(self, ctx):
        from wavlight.atomic import Terminated, terminate_as_exit

        with terminate_as_exit():
            try:
                return super().invoke(ctx)
            except KeyboardInterrupt:
                click.echo("Error: interrupted (SIGINT)", err=True)
                sys.exit(INTERRUPTED_EXIT_CODE)
            except Terminated:
                click.echo("Error: terminated (SIGTERM)", err=True)
                raise


@click.group(cls=_Commands, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="wavlight")
def main():
    """wavlight: render direct environment lighting with Haar wavelet importance sampling.

    Exit codes: 0 success; 2 bad input or options, or an output that could not be written
    (one 'Error:' line; render writes no image); 3 finished and written, but input was sanitised (NaN, Inf or negative texels set
    to 0, degenerate triangles removed; a 'warning:' line says which).
    """
    global _sanitised
    from wavlight.errors import SanitisedInputWarning

    _sanitised = False
    warnings.showwarning = _warn_line
    _show_library_notes()
    # shown once per invocation whatever the process saw before (a new filter also resets the
    # "once per location" registries) and whatever -W / PYTHONWARNINGS say: exit code 3 needs it
    warnings.filterwarnings("default", category=SanitisedInputWarning)


@main.result_callback()
def _exit_code(*args, **kwargs):
    """After a command that completed: exit code 3 if its input had to be sanitised."""
    from wavlight.errors import SANITISED_EXIT_CODE

    if _sanitised:
        sys.exit(SANITISED_EXIT_CODE)


def _strategy_options(command):
    """The strategies' and the sampler's flags, one per option of wavlight.strategies.OPTIONS (the one
    declaration of each range, default and help text); each is checked by its record."""
    def checked(option):
        def callback(ctx, param, value):
            why = None if value is None else option.problem(value)
            if why:
                raise click.BadParameter(why)
            return value
        return callback

    for option in reversed(list(OPTIONS.values())):
        applies = "every strategy" if set(APPLIES[option.key]) == set(STRATEGIES) else ", ".join(APPLIES[option.key])
        text = f"{option.help} Default: {option.default_text()}. ({applies})"
        if option.kind is bool:
            decorator = click.option(f"{option.flag}/{option.off_flag}", option.key, default=None, help=text)
        elif option.kind is str:
            decorator = click.option(option.flag, option.key, type=click.Choice(option.values), default=None,
                                     help=text)
        else:
            decorator = click.option(option.flag, option.key, type=int, default=None, metavar=option.allowed(),
                                     callback=checked(option), help=text)
        command = decorator(command)
    return command


def _scene_settings(*options):
    """Flags that override the scene file's [render] keys (their records: wavlight.options), checked
    by their records before the scene is read."""
    def decorate(command):
        for option in reversed(options):
            command = flag(option, f"the scene's [render] {option.key}, {option.default_text()} where it has "
                                   "none", checked=False)(command)
        return command
    return decorate


@main.command()
@click.argument("scene_file", metavar="[SCENE]", required=False, type=click.Path(dir_okay=False))
@click.option("--demo", default=None, metavar="NAME",
              help="Render the shipped scene NAME instead of a file (`wavlight scenes` lists them).")
@click.option("--env", "env", default=None, metavar="MAP",
              help="With a mesh file (.glb .gltf .obj) as SCENE: the environment map (a file or data:NAME; "
                   "default: the procedural sky). The file's glTF camera, else one that frames its bounds.")
@click.option("-o", "--output", default=None, help="Output image (.exr .hdr .pfm linear; .png sRGB). "
              "Default: the scene's name with .png.")
@_scene_settings(SPP)
@click.option("--strategy", type=click.Choice(STRATEGIES),
              default=None, help="Sampling strategy (overrides the scene).")
@_scene_settings(WIDTH, HEIGHT, SEED)
@flag(BACKGROUND, "the scene's [environment] background, nearest where it has none")
@_strategy_options
@click.option("--stderr-out", "stderr_out", default=None, metavar="FILE",
              help="Also write each pixel's standard error of the mean (linear: .exr .hdr .pfm; needs spp >= 2).")
@flags(DISPLAY)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object with settings and timings.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar and no closing message.")
def render(scene_file, demo, env, output, spp, strategy, width, height, seed, background, stderr_out, exposure,
           tonemap, as_json, quiet, **options):
    """Render SCENE (a TOML scene file, or a .glb, .gltf or .obj mesh file with its materials), or the
    shipped scene --demo NAME, to an image."""
    import time

    import numpy as np

    import wavlight
    from wavlight.imageio import FORMATS, LINEAR, check_display, provenance

    t0 = time.perf_counter()
    if (scene_file is None) == (demo is None):
        fail("give a SCENE file or --demo NAME, not both" if demo is not None
             else "give a SCENE file, or --demo NAME for a shipped scene (`wavlight scenes` lists them)")
    if demo is not None:
        from wavlight import demos
        try:
            scene_file = str(demos.path(demo))
        except wavlight.WavlightError as e:
            fail(e)
    if output is None:
        output = os.path.splitext(os.path.basename(scene_file.removeprefix("data:")))[0] + ".png"
    check_output(output, FORMATS)
    look = given({"exposure": exposure, "tonemap": tonemap})
    try:
        check_display([output], **look)
    except wavlight.WavlightError as e:
        fail(e)
    if stderr_out is not None:
        check_output(stderr_out, LINEAR)
        if os.path.abspath(stderr_out) == os.path.abspath(output):
            fail(f"{stderr_out}: --stderr-out must differ from the output image")
    for option, value in ((SPP, spp), (WIDTH, width), (HEIGHT, height), (SEED, seed)):
        why = None if value is None else option.problem(value)
        if why:
            fail(f"{option.flag} {why}")
    is_asset = wavlight.assets.renders_directly(scene_file)
    if env is not None and not is_asset:
        fail(f"--env applies to a mesh file rendered directly ({', '.join(wavlight.assets.SUFFIXES)}), not to "
             f"{scene_file}: a scene file names its map in [environment]")
    try:
        if is_asset:
            scene = wavlight.load_asset(scene_file, env, width, height)
        else:
            scene = wavlight.load_scene(scene_file)
        for name in (output, stderr_out):   # an output must not overwrite the scene or a file it reads
            if name is not None:
                refuse_inputs(name, [scene_file, *scene.files])
        if scene.environment.is_black:
            fail(f"{scene_file}: [environment]: the environment is black everywhere; "
                  "the image would be black")
        if stderr_out is not None and (scene.spp if spp is None else spp) < 2:
            fail(f"{stderr_out}: a standard error needs spp >= 2")
        with progress_bar("parts", "samples", quiet) as bar:
            result = wavlight.render_full(scene, spp=spp, strategy=strategy, width=width, height=height,
                                          seed=seed, progress=bar, background=background, **options)
        bad = int((~np.isfinite(result.image)).any(axis=-1).sum())
        if bad:   # (the inputs are finite and bounded: an estimate overflowed float32)
            fail(f"{output}: {bad} pixel(s) came out NaN or Inf (an estimate radiance x BRDF / pdf overflowed "
                  "float32; try another strategy or a dimmer map); nothing written")
        # the image and its standard errors appear together or not at all
        st = result.stats
        wavlight.imageio.save_images([(output, result.image)]
                                     + ([] if stderr_out is None else [(stderr_out, result.stderr)]), **look,
                                     metadata=provenance(st["strategy"], st["spp"], st["seed"], scene.content_hash))
    except wavlight.WavlightError as e:
        fail(e)
    stats = dict(result.stats)
    stats["load_seconds"] = round(time.perf_counter() - t0 - stats["setup_seconds"] - stats["render_seconds"], 4)
    stats["output"] = output
    if stderr_out is not None:
        stats["stderr_output"] = stderr_out
    if as_json:
        click.echo(json.dumps(stats))
    elif not quiet:
        how = stats["strategy"]
        if stats.get("wavelet_candidates"):   # the resampling estimator's budget, chosen or given
            how += f" ({stats['wavelet_candidates']} candidates, {stats['wavelet_slots']} slots)"
        click.echo(f"wrote {output}: {stats['width']}x{stats['height']}, {stats['spp']} spp, "
                   f"{how}, render {stats['render_seconds']:.2f} s "
                   f"({stats['samples_per_second'] / 1e6:.2f} M samples/s)", err=True)


@main.command()
def scenes():
    """List the shipped scenes (wavlight render --demo NAME renders one)."""
    from wavlight import demos

    described = demos.describe()
    width = max(map(len, described), default=0)
    for name, text in described.items():
        click.echo(f"{name:<{width}}  {text}")


@main.command()
def info():
    """Versions, the OpenCL platforms and devices, the one in use and why."""
    import numpy

    import wavlight
    from wavlight import cl, icd

    click.echo(f"wavlight {wavlight.__version__}")
    devices = cl.list_devices()   # (registers the pip-installed drivers first)
    import pyopencl

    click.echo(f"python {sys.version.split()[0]}, numpy {numpy.__version__}, pyopencl {pyopencl.VERSION_TEXT}")
    for driver in icd.register():
        click.echo(f"pip-installed OpenCL driver: {driver.distribution} ({driver.library})")
    for pi, di, p, d in devices:
        click.echo(f"  [{pi}:{di}] {p.name} {p.version.strip()} / {d.name}")
    try:
        rt = cl.runtime()
        click.echo(f"device in use: {rt.description}")
        click.echo(f"why: {rt.reason}")
        click.echo("OpenCL builtins: " + ("inlined (kernels/simd.h)" if cl.builtins_inlined()
                                          else "the device's library"))
    except wavlight.WavlightError as e:
        fail(e)
    click.echo(f"(set {cl.DEVICE_ENV}=P:D or a name fragment to choose another)")
    from wavlight import data
    try:
        click.echo(f"data folder: {data.data_dir()} (fetched assets; set {data.DATA_ENV} to choose another)")
    except wavlight.WavlightError as e:
        fail(e)


from .experiment import experiment  # noqa: E402
from .relight import bake, frame  # noqa: E402
from .view import view  # noqa: E402

for _command in (experiment, bake, frame, view):
    main.add_command(_command)

if __name__ == "__main__":
    main()
