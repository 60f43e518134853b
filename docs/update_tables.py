"""Rewrite the generated option tables of the docs from the settings' one declaration.

    python docs/update_tables.py

Each table sits between the lines ``<!-- NAME:begin -->`` and ``<!-- NAME:end -->`` of its file
(:func:`tables` lists them): the strategies' options (wavlight.strategies.options_table), the
render's own settings (wavlight.options), the display transform of PNG outputs (wavlight.display),
and the settings of ``wavlight bake``, ``frame`` and
``view`` (wavlight.relight.settings.options_table). tests/test_settings.py and
tests/test_layout.py check that they are current.
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent


def tables() -> dict:
    """{file name: {marker name: table}} of every generated table."""
    from wavlight import display, options, strategies
    from wavlight.relight import settings

    render = options.markdown_table([options.SPP, options.WIDTH, options.HEIGHT, options.SEED])
    approximate = ("refine", "mass", "mode", "supersample", "tau")
    return {
        "cli.md": {"render": render, "options": strategies.options_table(True),
                   "display": options.markdown_table(display.DISPLAY, scene_keys=False),
                   "bake": settings.options_table("bake"),
                   "frame": settings.options_table("frame"), "view": settings.options_table("view")},
        "scene-format.md": {"options": strategies.options_table(True)},
        "relight.md": {"bake": settings.options_table("bake", keywords=True),
                       "view-frame": settings.options_table("frame", keywords=True, keys=approximate)},
    }


def updated(text: str, found: dict, name: str) -> tuple[str, list]:
    """``text`` with each table of ``found`` between its markers, and the problems (a marker pair
    missing or repeated) in ``name``."""
    problems = []
    for marker, table in found.items():
        text, count = re.subn(rf"(<!-- {marker}:begin -->\n)(?:.*?\n)?(<!-- {marker}:end -->)",
                              lambda m: m.group(1) + table + "\n" + m.group(2), text, flags=re.S)
        if count != 1:
            problems.append(f"{name}: expected one pair of <!-- {marker}:begin/end --> markers, found {count}")
    return text, problems


def main() -> int:
    status = 0
    for name, found in tables().items():
        path = DOCS / name
        text = path.read_text()
        new, problems = updated(text, found, name)
        for problem in problems:
            print(problem, file=sys.stderr)
            status = 1
        if new != text and not problems:
            path.write_text(new)
            print(f"updated {path}")
    return status


if __name__ == "__main__":
    sys.exit(main())
