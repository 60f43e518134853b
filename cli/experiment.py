"""`wavlight experiment SPEC -o DIR`: a thin layer over :func:`wavlight.evaluation.experiment.run_experiment`.

`wavlight experiment --suite stability -o DIR` runs a built-in suite instead of a spec file
(:func:`wavlight.evaluation.experiment.run_suite`; the stability suite is :mod:`wavlight.evaluation.stability`) and
prints its table.

``--workers N`` renders the runs in N spawned local processes, ``--dask tcp://HOST:PORT``
on an existing dask.distributed scheduler; references and pilots stay in this process.

A progress bar over runs (references, pilots and runs; finished runs count as done) is
drawn on stderr when it is a terminal, never with ``--quiet``. The summary table goes
to stdout. Bad input prints one line ``Error: FILE: [table].key: problem`` and exits 2
(runs finished before the error stay in DIR, for a resume). A spec whose scenes had to be
sanitised (NaN, Inf or negative texels; degenerate triangles) runs and then exits 3, as
``render`` does; the stability suite, whose cases are such input on purpose, records those
warnings in its results and exits 0.
"""
from __future__ import annotations

import click

from .progress import progress_bar


class _InputError(click.ClickException):
    exit_code = 2


@click.command()
@click.argument("spec_file", metavar="[SPEC]", required=False, type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out_dir", metavar="DIR", required=True, type=click.Path(),
              help="Output folder: results.csv/.json, charts/, runs/, reference/.")
@click.option("--suite", type=click.Choice(["stability"]), default=None,
              help="Run a built-in suite instead of SPEC (stability: adversarial maps x every strategy; "
                   "writes stability.csv/.json and charts/stability.png/.svg).")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar and no closing message.")
@click.option("--no-resume", is_flag=True, help="Render every run again (default: reuse finished runs).")
@click.option("--workers", type=click.IntRange(min=1), default=1, show_default=True,
              help="Render runs in N local processes (spawned; 1 = in this process). Metrics are identical; "
                   "timings then include contention between concurrent renders.")
@click.option("--dask", "dask_address", metavar="tcp://HOST:PORT", default=None,
              help="Submit the runs to this dask.distributed scheduler (workers need the scene files at the "
                   "same paths). Not with --workers.")
def experiment(spec_file, out_dir, suite, quiet, no_resume, workers, dask_address):
    """Run the batch experiment SPEC (TOML), or a built-in --suite, into the folder -o DIR.

    Renders every scene x strategy x budget x seed, measures each against the reference
    (relMSE, MSE, variance, bias, largest error) and writes results.csv/.json and charts.
    Runs finished by an earlier call are reused. Format: docs/experiments.md.
    With --suite stability, runs the stability suite instead (docs/experiments.md)."""
    import wavlight
    from wavlight.evaluation import format_summary, run_experiment, run_suite
    from wavlight.evaluation.experiment import MAX_WORKERS

    if workers > MAX_WORKERS:
        raise click.BadParameter(f"{workers} is more than {MAX_WORKERS} local processes; for more, "
                                 "give a Dask scheduler with --dask", param_hint="'--workers'")
    if (spec_file is None) == (suite is None):
        raise _InputError("give either SPEC or --suite NAME")
    if dask_address is not None and workers != 1:
        raise _InputError("give either --workers or --dask, not both")
    if suite is not None and (dask_address is not None or workers != 1):
        raise _InputError("--workers and --dask apply to SPEC runs, not to --suite")
    try:
        with progress_bar("runs", quiet=quiet) as bar:
            if suite is not None:
                results, table = run_suite(suite, out_dir, progress=bar)
            else:
                results = run_experiment(spec_file, out_dir, progress=bar, resume=not no_resume, workers=workers,
                                         dask_address=dask_address)
                table = format_summary(results)
    except wavlight.WavlightError as e:
        raise _InputError(str(e)) from None
    click.echo(table)
    if not quiet:
        what = "stability.csv, stability.json, charts/" if suite else "results.csv, results.json, charts/"
        click.echo(f"wrote {out_dir}: {what} ({results['seconds']:.1f} s)", err=True)
