"""Settings declared once: the :class:`Option` record of a strategy parameter or render setting.

Each strategy names its options next to its class (``Strategy.options``: constructor parameter
-> Option, :mod:`wavlight.strategies`), the sampler its own (:data:`wavlight.sampler.SAMPLER`);
the registry (:data:`wavlight.strategies.OPTIONS`) collects them by key. Everything else is
derived from these records: the ``[render]`` keys of scene files, the ``wavlight render`` flags,
the ``[[strategies]]`` keys of experiment files, the keywords of :func:`wavlight.render_full`,
the strategies' own argument checks and the option tables of the docs
(:func:`markdown_table`). A range, a default or a help text is written once, here or in the
strategy module that declares it.

A :class:`Constraint` ties two options (``wavelet_slots = 4`` needs ``wavelet_candidates`` other
than 0); it is checked wherever both values are known.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .errors import ArgumentError, shown

KINDS = (int, str, bool)


@dataclass(frozen=True)
class Option:
    """One setting.

    key : the scene file's ``[render]`` key, the experiment's ``[[strategies]]`` key and the
        :func:`wavlight.render_full` keyword; the flag is ``--`` + key with dashes
        (``--no-...`` for the off switch of a bool)
    kind : int, str or bool
    help : one sentence for ``--help`` and the docs
    default : the value when nothing sets it; None: chosen at render time (``default_doc`` says how)
    lo, hi : the range of an int
    values : the allowed values (strings, or ints from [lo, hi]); empty: the whole range
    refused : values in range that are refused, with the phrase that says what is allowed instead
    """

    key: str
    kind: type
    help: str
    default: object = None
    default_doc: str = ""
    lo: int | None = None
    hi: int | None = None
    values: tuple = ()
    refused: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise TypeError(f"Option {self.key}: kind must be one of int, str, bool")

    @property
    def flag(self) -> str:
        return "--" + self.key.replace("_", "-")

    @property
    def off_flag(self) -> str:
        """The off switch of a bool option (``--no-wavelet-control-variate``)."""
        return "--no-" + self.key.replace("_", "-")

    def allowed(self) -> str:
        """The allowed values in words: ``0 | 2..64``, ``2 | 4``, ``1..11``, ``a | b``, ``true | false``."""
        if self.kind is bool:
            return "true | false"
        if self.values:
            return " | ".join(str(v) for v in self.values)
        lo, hi = self.lo, self.hi
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
        return str(self.default)

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
        if not isinstance(value, str):
            return f"must be a string ({self.allowed()}), got {shown(value)}"
        if self.values and value not in self.values:
            return f"must be one of {self.allowed()}, got {shown(value)}"
        return None

    def check(self, value, where: str, name: str | None = None):
        """``value`` normalised (a Python int, str or bool), or an :class:`ArgumentError`
        ``where: name must be ...``; ``name`` defaults to the key."""
        why = self.problem(value)
        if why is not None:
            raise ArgumentError(f"{where}: {name or self.key} {why}")
        return self.kind(value)


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


def markdown_table(options, applies: dict, scene_keys: bool = True) -> str:
    """The docs' table of options: flag, scene key, values, default, strategies, meaning."""
    head = ["flag", "scene key" if scene_keys else None, "values", "default", "strategies", "meaning"]
    head = [h for h in head if h]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for o in options:
        flag = f"`{o.flag}` / `{o.off_flag}`" if o.kind is bool else f"`{o.flag}`"
        cells = [flag] + ([f"`{o.key}`"] if scene_keys else [])
        cells += [o.allowed(), o.default_text(), ", ".join(applies[o.key]), o.help]
        rows.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(rows)
