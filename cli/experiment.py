"""`wavlight experiment SPEC -o DIR`: a thin layer over :func:`wavlight.experiment.run_experiment`.

A progress bar over runs (references, pilots and runs; finished runs count as done) is
drawn on stderr when it is a terminal, never with ``--quiet``. The summary table goes
to stdout. Bad input prints one line ``Error: FILE: [table].key: problem`` and exits 2.
"""
from __future__ import annotations

import sys
import time

import click


class _InputError(click.ClickException):
    exit_code = 2


class RunBar:
    """One terminal line: runs done of total, elapsed time, the run just finished."""

    def __init__(self, stream, width=24):
        self.stream, self.width, self.t0 = stream, width, time.perf_counter()

    def __call__(self, done, total, what):
        fill = int(done / max(total, 1) * self.width)
        secs = int(time.perf_counter() - self.t0)
        line = f"[{'#' * fill}{'.' * (self.width - fill)}] {done}/{total} runs  {secs // 60}:{secs % 60:02d}  {what}"
        self.stream.write("\r" + line[:110].ljust(110))
        self.stream.flush()

    def close(self):
        self.stream.write("\n")
        self.stream.flush()


@click.command()
@click.argument("spec_file", metavar="SPEC", type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out_dir", metavar="DIR", required=True, type=click.Path(),
              help="Output folder: results.csv/.json, charts/, runs/, reference/.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar and no closing message.")
@click.option("--no-resume", is_flag=True, help="Render every run again (default: reuse finished runs).")
def experiment(spec_file, out_dir, quiet, no_resume):
    """Run the batch experiment SPEC (TOML) into the folder DIR.

    Renders every scene x strategy x budget x seed, measures each against the reference
    (relMSE, MSE, variance, bias, largest error) and writes results.csv/.json and charts.
    Runs finished by an earlier call are reused. Format: see wavlight/experiment.py."""
    import wavlight
    from wavlight.experiment import format_summary, run_experiment

    bar = None if quiet or not sys.stderr.isatty() else RunBar(sys.stderr)
    try:
        results = run_experiment(spec_file, out_dir, progress=bar, resume=not no_resume)
    except wavlight.WavlightError as e:
        if bar:
            bar.close()
        raise _InputError(str(e)) from None
    if bar:
        bar.close()
    click.echo(format_summary(results))
    if not quiet:
        click.echo(f"wrote {out_dir}: results.csv, results.json, charts/ ({results['seconds']:.1f} s)", err=True)
