"""The Philox stream registry (wavlight.rng.STREAMS): no two streams share an id, kernels/rng.h
defines the ids the kernels name with rng.py's values, and no other module assigns a stream."""
from __future__ import annotations

import re
from pathlib import Path

from wavlight import rng

ROOT = Path(__file__).resolve().parents[1]


def header_ids() -> dict:
    """RNG_NAME -> id of every ``#define RNG_NAME <id>u`` in kernels/rng.h."""
    text = (ROOT / "kernels" / "rng.h").read_text()
    return {m[1]: int(m[2]) for m in re.finditer(r"^#define RNG_(\w+)\s+(\d+)u?\b", text, re.M)}


def test_no_two_streams_share_an_id():
    owner = {}
    for name, ids in rng.STREAMS.items():
        assert len(ids) >= 1, name
        for i in ids:
            assert i not in owner, f"stream id {i} is both {owner[i]}'s and {name}'s"
            owner[i] = name


def test_registry_names_the_module_constants():
    for name, ids in rng.STREAMS.items():
        value = getattr(rng, name)
        assert (value if isinstance(value, range) else range(value, value + 1)) == ids, name


def test_rng_h_defines_the_registry_ids():
    ids = header_ids()
    assert {"JITTER", "SHADING", "STRATA"} <= set(ids)
    for name, value in ids.items():
        assert name in rng.STREAMS, f"kernels/rng.h: RNG_{name} is not a stream of wavlight/rng.py"
        assert rng.STREAMS[name] == range(value, value + 1), f"RNG_{name} = {value}, rng.py: {rng.STREAMS[name]}"


def test_kernels_name_only_the_streams_of_rng_h():
    defined = set(header_ids())
    for path in sorted((ROOT / "kernels").glob("*.[ch]*")):
        text = path.read_text()
        if path.name != "rng.h":
            assert "#define RNG_" not in text, f"{path.name} defines a stream: declare it in rng.py and rng.h"
        used = set(re.findall(r"\bRNG_([A-Z0-9_]+)\b", text))
        assert used <= defined, f"{path.name} uses {sorted(used - defined)}, not in rng.h"


def test_no_other_module_assigns_a_stream():
    pattern = re.compile(r"^\s*[A-Z_]*STREAMS?\b[\w, ]*=", re.M)
    for path in sorted((ROOT / "wavlight").rglob("*.py")):
        if path == ROOT / "wavlight" / "rng.py":
            continue
        assert not pattern.search(path.read_text()), f"{path.relative_to(ROOT)} assigns a stream id"
