"""What the commands share: one-line errors and the checks of an output path before any work."""
from __future__ import annotations

import os

import click

from wavlight.atomic import check_target
from wavlight.errors import WavlightError, one_line
from wavlight.imageio import check_not_input


def fail(message) -> None:
    raise click.ClickException(one_line(message))


def check_output(path, formats=None, what="an image file"):
    """Before any work: a known extension (of ``formats``; None: any name), a folder that exists
    and can be written, not a read-only file (:func:`wavlight.atomic.check_target`)."""
    if formats is not None and not os.path.isdir(path) and os.path.splitext(path)[1].lower() not in formats:
        fail(f"{path}: unsupported output format (use {', '.join(formats)})")
    try:
        check_target(path, what)
    except WavlightError as e:
        fail(e)


def refuse_inputs(output, inputs):
    """An output that names one of the run's inputs (scene, map, mesh, bake file; also through a
    link) would destroy it: refused before any work (:func:`wavlight.imageio.check_not_input`)."""
    try:
        check_not_input([output], inputs)
    except WavlightError as e:
        fail(e)
