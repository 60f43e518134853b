"""Rewrite the generated option tables of the docs from the options' one declaration.

    python docs/update_tables.py

Each file below carries wavlight.strategies.options_table() between the lines
``<!-- options:begin -->`` and ``<!-- options:end -->``; tests/test_layout.py checks that they
are current.
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

from wavlight import strategies

DOCS = Path(__file__).resolve().parent
FILES = {"cli.md": True, "scene-format.md": True}


def main() -> int:
    for name, scene_keys in FILES.items():
        path = DOCS / name
        text = path.read_text()
        table = strategies.options_table(scene_keys)
        new, count = re.subn(r"(<!-- options:begin -->\n).*?(\n<!-- options:end -->)",
                             lambda m: m.group(1) + table + m.group(2), text, flags=re.S)
        if count != 1:
            print(f"{path}: expected one pair of option-table markers, found {count}", file=sys.stderr)
            return 1
        if new != text:
            path.write_text(new)
            print(f"updated {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
