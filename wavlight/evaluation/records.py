"""An experiment's files: atomic text, JSON and CSV, run images and their checks, content hashes."""
from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import numbers
import os

import numpy as np

from ..errors import WavlightError
from ..atomic import TEMPORARY_PREFIX, atomic_write, remove_stale_temporaries, size_is


def content_hash(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()[:16]


def write_text(path, text):
    """Atomically (:func:`wavlight.atomic.atomic_write`): a temporary file in the same folder,
    checked for its size, renamed over the target."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    data = text.encode("utf-8")
    with atomic_write(path, check=size_is(len(data)), suffix=".tmp") as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)


def json_safe(obj):
    """obj with every non-finite float as None (JSON has no NaN or Infinity)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


def write_json(path, obj):
    write_text(path, json.dumps(json_safe(obj), indent=1, allow_nan=False) + "\n")


def read_json(path):
    """The JSON value in the file, or None when it is missing, unreadable or not JSON (also
    JSON nested too deeply for the parser)."""
    try:
        with open(path) as fh:
            return json.load(fh)
    except (OSError, ValueError, RecursionError, MemoryError):
        return None


#: Kinds of record fields for :func:`record_problem`.
NUMBER, INTEGER, TEXT, TABLE, ROWS = "number", "integer", "text", "table", "rows"


def _is(kind, v) -> bool:
    if kind == NUMBER:
        return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)
    if kind == INTEGER:
        return isinstance(v, int) and not isinstance(v, bool)
    if kind == TEXT:
        return isinstance(v, str)
    if kind == TABLE:
        return isinstance(v, dict)
    if kind == ROWS:
        return isinstance(v, list)
    raise ValueError(kind)


def record_problem(rec, fields: dict) -> str | None:
    """Why a resume record (a run's, a reference's, a pilot's JSON) cannot be used, or None:
    not a JSON object, or a field missing or of the wrong kind (``fields``: name -> kind,
    kinds NUMBER, INTEGER, TEXT, TABLE, ROWS; a tuple of kinds allows either, None too)."""
    if not isinstance(rec, dict):
        return f"is not a JSON object (it holds {type(rec).__name__ if rec is not None else 'null'})"
    for name, kinds in fields.items():
        kinds = kinds if isinstance(kinds, tuple) else (kinds,)
        v = rec.get(name)
        if v is None and None in kinds:
            continue
        if name not in rec:
            return f"has no {name!r}"
        if not any(k is not None and _is(k, v) for k in kinds):
            return f"has a {name!r} of the wrong kind ({type(v).__name__})"
    return None


def remove_stale(out_dir) -> list:
    """The temporaries that killed writers left anywhere in an experiment folder (records.
    write_text's and imageio's, :func:`wavlight.atomic.remove_stale_temporaries`): removed at
    the start of each run. Returns their paths."""
    removed = []
    for folder, _, names in os.walk(out_dir):
        if any(n.startswith(TEMPORARY_PREFIX) for n in names):
            removed += [os.path.join(folder, n) for n in remove_stale_temporaries(folder)]
    return removed


def read_image(path):
    from ..envmap import read_image
    return read_image(path)


def image_problem(path, width, height):
    """Why a finished run's image cannot be reused (None: it can): missing, unreadable (a
    truncated or corrupt file), another size, or NaN / Inf pixels."""
    if not os.path.isfile(path):
        return "is missing"
    try:
        image = read_image(path)
    except (WavlightError, ValueError, OSError, MemoryError):
        return "cannot be read"
    if image.shape != (height, width, 3):
        return f"has shape {image.shape}, not ({height}, {width}, 3)"
    bad = int((~np.isfinite(image)).any(axis=-1).sum())
    return f"has {bad} NaN or Inf pixel(s)" if bad else None


def save_run_image(path, image):
    from ..imageio import save_image
    os.makedirs(os.path.dirname(path), exist_ok=True)
    save_image(path, image)


def csv_text(rows, columns) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for row in rows:
        w.writerow(["" if row.get(c) is None else row[c] for c in columns])
    return buf.getvalue()
