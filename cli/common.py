"""What the commands share: one-line errors and the checks of an output path before any work."""
from __future__ import annotations

import os

import click

from wavlight.errors import WavlightError, one_line
from wavlight.imageio import check_not_input


def fail(message) -> None:
    raise click.ClickException(one_line(message))


def check_output(path, formats):
    """Before rendering: a known extension, a folder that exists and can be written."""
    if os.path.isdir(path):
        fail(f"{path}: is a folder, not an image file")
    if os.path.splitext(path)[1].lower() not in formats:
        fail(f"{path}: unsupported output format (use {', '.join(formats)})")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        fail(f"{path}: no folder {folder}")
    if not os.access(folder, os.W_OK):
        fail(f"{path}: cannot write into {folder}")
    # the file is replaced by a rename, which a read-only file would not stop: refuse a file that
    # the caller cannot write or that has no write permission at all (also for root)
    if os.path.isfile(path) and (not os.access(path, os.W_OK) or not os.stat(path).st_mode & 0o222):
        fail(f"{path}: the file exists and is read-only")


def refuse_inputs(output, inputs):
    """An output that names one of the run's inputs (scene, map, mesh, bake file; also through a
    link) would destroy it: refused before any work (:func:`wavlight.imageio.check_not_input`)."""
    try:
        check_not_input([output], inputs)
    except WavlightError as e:
        fail(e)
