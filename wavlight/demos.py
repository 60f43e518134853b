"""The example scenes that ship with wavlight: list them and find one by name.

    wavlight.demos.names()            # ["default", "spot_ggx", ...]
    wavlight.demos.describe()         # {name: its one-line description}
    wavlight.demos.path("spot_ggx")   # its file, for wavlight.load_scene

They are the repository's ``scenes/*.toml``, installed as the package ``wavlight.scenes``, so
that a user without the repository can list and render them (``wavlight scenes``,
``wavlight render --demo NAME``). A scene's description is the first line of its file, a
comment. Each names only built-in shapes, the
procedural sky and shipped assets (``data:``, :mod:`wavlight.data`): every one renders offline.
"""
from __future__ import annotations

import difflib
from importlib import resources
from pathlib import Path

from .errors import WavlightError


def folder() -> Path:
    """The installed scenes' folder."""
    return Path(str(resources.files("wavlight.scenes")))


def names() -> list:
    """The shipped scenes' names (file names without ``.toml``), sorted."""
    return sorted(p.stem for p in folder().glob("*.toml"))


def path(name: str) -> Path:
    """The file of shipped scene ``name``; an unknown name is one line listing the scenes."""
    known = names()
    if name not in known:
        close = difflib.get_close_matches(str(name), known, n=3, cutoff=0.5)
        hint = f"did you mean {', '.join(close)}? " if close else ""
        raise WavlightError(f"no shipped scene {name!r} ({hint}scenes: {', '.join(known)}; `wavlight scenes` "
                            "lists them)")
    return folder() / f"{name}.toml"


def description(name: str) -> str:
    """The first line of scene ``name``'s file, a comment, without its ``#`` (empty when the
    file starts otherwise)."""
    with open(path(name), encoding="utf-8") as fh:
        first = fh.readline()
    return first.lstrip("#").strip() if first.startswith("#") else ""


def describe() -> dict:
    """Every shipped scene's one-line description, by name."""
    return {name: description(name) for name in names()}
