"""Settings declared once: the :class:`Option` record of a render, strategy, bake, frame or viewer
setting.

Each strategy names its options next to its class (``Strategy.options``: constructor parameter
-> Option, :mod:`wavlight.strategies`), the sampler its own (:data:`wavlight.sampler.SAMPLER`);
the registry (:data:`wavlight.strategies.OPTIONS`) collects them by key. The render's own
settings (:data:`SPP`, :data:`WIDTH`, :data:`HEIGHT`, :data:`SEED`) are here, the relighting's
in :mod:`wavlight.relight.settings`. Everything else is derived from these records: the
``[render]`` keys of scene files, the flags of ``wavlight render``, ``bake``, ``frame`` and
``view``, the ``[[strategies]]`` keys of experiment files, the keywords' defaults of
:func:`wavlight.render_full` and :func:`wavlight.bake`, the argument checks and the option tables
of the docs (:func:`markdown_table`). A range, a default or a help text is written once, here or
in the module that declares the record.

A :class:`Constraint` ties two options (``wavelet_slots = 4`` needs ``wavelet_candidates`` other
than 0); it is checked wherever both values are known.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .errors import ArgumentError, shown

KINDS = (int, float, str, bool)


@dataclass(frozen=True)
class Option:
    """One setting.

    key : the scene file's ``[render]`` key, the experiment's ``[[strategies]]`` key and the
        library's keyword (:func:`wavlight.render_full`, :func:`wavlight.bake`, ...); the flag is
        ``--`` + key with dashes (``--no-...`` for the off switch of a bool) unless ``flag_name``
        names another
    kind : int, float, str or bool
    help : one sentence for ``--help`` and the docs
    default : the value when nothing sets it; None: chosen at run time or not used
        (``default_doc`` says which)
    lo, hi : the range of an int or a float (inclusive)
    values : the allowed values (strings, or ints from [lo, hi]); empty: the whole range
    refused : values in range that are refused, with the phrase that says what is allowed instead
    count : numbers per value (``--eye X Y Z``: 3)
    flag_name : the flag where it is not ``--`` + key with dashes (``--dask`` for ``dask_address``)
    metavar : the value's name in ``--help`` (``FILE``, ``X Y Z``); default the allowed values
    negatable : a bool's flag has an off switch (``--x/--no-x``); False: a plain switch
    repeatable : the flag may be given several times (the value is a tuple of them)
    """

    key: str
    kind: type
    help: str
    default: object = None
    default_doc: str = ""
    lo: float | None = None
    hi: float | None = None
    values: tuple = ()
    refused: dict = field(default_factory=dict)
    count: int = 1
    flag_name: str = ""
    metavar: str = ""
    negatable: bool = True
    repeatable: bool = False

    def __post_init__(self):
        if self.kind not in KINDS:
            raise TypeError(f"Option {self.key}: kind must be one of int, float, str, bool")
        if self.default is None and not self.default_doc:
            raise TypeError(f"Option {self.key}: a default of None needs default_doc (what happens instead)")

    @property
    def flag(self) -> str:
        return self.flag_name or "--" + self.key.replace("_", "-")

    @property
    def off_flag(self) -> str:
        """The off switch of a bool option (``--no-wavelet-control-variate``)."""
        return "--no-" + self.key.replace("_", "-")

    def allowed(self) -> str:
        """The allowed values in words: ``0 | 2..64``, ``2 | 4``, ``1..11``, ``0.0001..100``,
        ``a | b``, ``true | false``; a value without a range (a file, a name): its metavar."""
        if self.kind is bool:
            return "true | false"
        if self.values:
            return " | ".join(str(v) for v in self.values)
        if self.kind is str or self.lo is None and self.hi is None:
            return self.metavar or ("text" if self.kind is str else "numbers" if self.count > 1 else "a number")
        if self.kind is float:
            return f"{_number(self.lo)}..{_number(self.hi)}"
        lo, hi = self.lo, self.hi
        if hi is not None and not self.refused:
            return f"{lo if lo is not None else ''}..{_power(hi)}"
        refused = sorted(v for v in self.refused if lo is not None and lo <= v <= (hi if hi is not None else v))
        if refused and lo is not None and hi is not None and refused == list(range(refused[0], refused[-1] + 1)):
            parts = [f"{lo}..{refused[0] - 1}" if refused[0] - 1 > lo else str(lo)] if refused[0] > lo else []
            parts.append(f"{refused[-1] + 1}..{hi}")
            return " | ".join(parts)
        return f"{lo if lo is not None else ''}..{hi if hi is not None else ''}"

    def default_text(self) -> str:
        if self.default_doc:
            return self.default_doc
        if self.kind is bool:
            return "on" if self.default else "off"
        return _number(self.default) if self.kind is float else str(self.default)

    def problem(self, value) -> str | None:
        """Why ``value`` is not allowed (a phrase after the option's name), or None."""
        if self.kind is bool:
            return None if isinstance(value, (bool, np.bool_)) else f"must be true or false, got {shown(value)}"
        if self.kind is int:
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
                return f"must be an integer, got {shown(value)}"
            if value in self.refused:
                return f"must be {self.allowed()} ({self.refused[value]}), got {value}"
            if self.values and value not in self.values:
                return f"must be {self.allowed()}, got {value}"
            if self.lo is not None and value < self.lo or self.hi is not None and value > self.hi:
                return f"must be between {self.lo} and {self.hi}, got {value}"
            return None
        if self.kind is float:   # the words of wavlight.errors.check_number
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
                return f"must be a number, got {shown(value)}"
            if not math.isfinite(value) or self.lo is not None and value < self.lo \
                    or self.hi is not None and value > self.hi:
                bound = (f" in [{self.lo:g}, {self.hi:g}]" if self.lo is not None and self.hi is not None
                         else f" >= {self.lo:g}" if self.lo is not None
                         else f" <= {self.hi:g}" if self.hi is not None else "")
                return f"must be a finite number{bound}, got {value}"
            return None
        if not isinstance(value, str):
            return f"must be a string ({self.allowed()}), got {shown(value)}"
        if self.values and value not in self.values:
            return f"must be one of {self.allowed()}, got {shown(value)}"
        return None

    def check(self, value, where: str, name: str | None = None):
        """``value`` normalised (a Python int, float, str or bool), or an :class:`ArgumentError`
        ``where: name must be ...``; ``name`` defaults to the key."""
        why = self.problem(value)
        if why is not None:
            raise ArgumentError(f"{where}: {name or self.key} {why}")
        return self.kind(value)


def _power(n: int) -> str:
    """A bound as the docs write it: 2^k or 2^k - 1 from 2^20 on (2^62, 2^63 - 1), smaller ones in digits."""
    for k in range(20, 64):   # exponents, not values
        if n == 1 << k:
            return f"2^{k}"
        if n == (1 << k) - 1:
            return f"2^{k} - 1"
    return str(n)


def _number(x) -> str:
    """A bound or default as the docs show it: 1e-06, 0.02, 1e+30 (``%g``), an int as it is."""
    return "" if x is None else f"{x:g}" if isinstance(x, float) else str(x)


@dataclass(frozen=True)
class Constraint:
    """A condition on two options' values, checked where both are set: ``ok(a, b)``, else the
    first key's error ``message``."""

    keys: tuple
    ok: Callable
    message: str

    def problem(self, values: dict):
        """(key, message) when the values set in ``values`` break the constraint, else None."""
        a, b = (values.get(k) for k in self.keys)
        if a is not None and b is not None and not self.ok(a, b):
            return self.keys[0], self.message
        return None


def markdown_table(options, applies: dict | None = None, scene_keys: bool = True, key_head: str = "scene key",
                   applies_head: str = "strategies") -> str:
    """The docs' table of options: flag, key (the scene key or the library's keyword, ``key_head``),
    values, default, where it applies (``applies``: key -> names, ``applies_head``; None: no
    such column), meaning."""
    head = ["flag", key_head if scene_keys else None, "values", "default",
            applies_head if applies is not None else None, "meaning"]
    head = [h for h in head if h]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for o in options:
        flag = f"`{o.flag}` / `{o.off_flag}`" if o.kind is bool and o.negatable else f"`{o.flag}`"
        cells = [flag] + ([f"`{o.key}`"] if scene_keys else [])
        cells += [o.allowed(), o.default_text()] + ([", ".join(applies[o.key])] if applies is not None else [])
        cells.append(o.help)
        rows.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(rows)


# ----------------------------------------------------------------------------- the render's settings
#: the render's samples per pixel, image size and seed: the scene file's [render] keys, the flags of
#: ``wavlight render`` and render_full's keywords (None there: the scene's value)
SPP = Option("spp", int, "Samples per pixel.", default=16, lo=1, hi=1_000_000)
WIDTH = Option("width", int, "Image width in pixels.", default=256, lo=1, hi=16384)
HEIGHT = Option("height", int, "Image height in pixels.", default=256, lo=1, hi=16384)
SEED = Option("seed", int, "Random seed: a render is a deterministic function of scene, settings and seed.",
              default=0, lo=0, hi=2 ** 63 - 1)
#: how camera rays that miss every object see the environment: the scene file's [environment]
#: background, the --background flag of ``wavlight render``, ``frame`` and ``view``. Display only:
#: the lighting stays the piecewise-constant map that sampling and the measurements rely on.
BACKGROUND = Option("background", str, "How camera rays that miss see the map: its nearest texel (the "
                    "piecewise-constant map the lighting is) or filtered bilinearly between texel centres "
                    "(wrapping in longitude, clamped at the poles), or not at all (none: black, what misses "
                    "contribute is 0); the lighting is the same either way.",
                    default="nearest", values=("nearest", "bilinear", "none"))
#: the camera's vertical field of view: the scene file's [camera] fov_y, a view bake's frames
FOV = Option("fov_y", float, "The vertical field of view, degrees.", default=35.0, lo=1e-3, hi=179.0)
