"""What the commands share: one-line errors, the checks of an output path before any work, and the
flags made from the settings' records (:class:`wavlight.options.Option`)."""
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


def flag(option, default_text: str | None = None, checked: bool = True):
    """The click option of a setting's record: its flag, its range or choices (checked by click
    where ``checked``, else by the command from the record), its metavar, and its help text with
    the default (``default_text``, or the record's). A flag left out gives None (a switch False,
    a repeatable flag ()), so that a command passes on only what was given and the library's
    default, the same record's, applies."""
    text = f"{option.help} Default: {option.default_text() if default_text is None else default_text}."
    if option.kind is bool:
        if option.negatable:
            return click.option(f"{option.flag}/{option.off_flag}", option.key, default=None, help=text)
        return click.option(option.flag, option.key, is_flag=True, default=False, help=text)
    kw = {"default": () if option.repeatable else None, "help": text, "multiple": option.repeatable}
    if option.count > 1:
        kw["nargs"] = option.count
    if option.values:
        kw["type"] = click.Choice([str(v) for v in option.values])
        if option.kind is int:
            kw["callback"] = lambda ctx, param, value: None if value is None else int(value)
    elif not checked or option.lo is None and option.hi is None:
        kw["type"] = option.kind
    else:
        kw["type"] = (click.IntRange if option.kind is int else click.FloatRange)(option.lo, option.hi)
    if option.kind is float:   # click's FloatRange lets NaN through (no comparison is true of it)
        kw["callback"] = _finite
    if option.metavar:
        kw["metavar"] = option.metavar
    return click.option(option.flag, option.key, **kw)


def _finite(ctx, param, value):
    """A float flag's value (or values) as given, NaN refused in click's words."""
    values = value if isinstance(value, tuple) else (value,)
    if any(v is not None and v != v for v in values):
        raise click.BadParameter("must be a finite number, got nan")
    return value


def flags(options):
    """A decorator adding :func:`flag` of each record, in order."""
    def decorate(command):
        for option in reversed(list(options)):
            command = flag(option)(command)
        return command
    return decorate


def given(values: dict, *keys) -> dict:
    """The settings among ``keys`` (default all) that were given: those present and not None."""
    return {k: values[k] for k in (keys or values) if values.get(k) is not None}
