"""Every bit of a bake file's header flipped, one at a time: one line or the unmodified file's
frame, never a crash (tests/test_bake_hostile.py flips a sample of them).

Small bakes of one scene (a ball over a floor under a sky with a sun, 16 x 12; the lighting
bake at 8 x 8 texels, and with ``--kinds`` the object and view bakes) are made in a temporary
folder. For each bit of the file's first bytes (the magic, the header's length and the header)
two files are read:

- ``raw``: the file with that bit flipped, read and relit with the file's own defaults;
- ``signed``: the bit flipped in the header's text and the header's checksum signed anew (as a
  forger would: the text's length too), where the text stays a JSON object, so that the checks
  of the header against its sections stand alone; relit with explicit settings (rotation, terms,
  priority; an object's place; a camera), so that a default no section describes does not
  count.

A third mode, ``section``, flips ``--section-flips`` bits (fixed seed) of each section's
contents and signs the section's CRC-32 and the header anew: a section no bake writes must be
refused, or give a frame that is finite (``finite``: another frame, as the contents changed).

Each outcome is ``error`` (a one-line WavlightError naming the file), ``same`` (a frame equal
to the unmodified file's), ``finite`` (section mode), or what went wrong: ``another frame``,
``a frame of NaN or Inf``, an exception's type, or ``crash`` (the worker process died: a
signal). Flips are read in worker processes (in the bakes' folder: a checkout's folder first
on sys.path would shadow a copy of the package given by PYTHONPATH), each going through a list
of bits in order and reporting each; a worker that dies is recorded as a crash at its current
bit and a new one goes on from the next. ``--cli N`` also runs N evenly spaced raw
flips of the lighting bake through the ``wavlight frame`` command (exit codes and the one
``Error:`` line).

    python benchmarks/bake_fuzz.py [--kinds lighting,object,view] [--cli 64] [--section-flips 64] [--compare FILE]
                                   [-o FILE]

``--compare FILE`` keeps the outcome counts of another run under ``compared`` (say one with
PYTHONPATH at a copy of the package of another commit).

Writes benchmarks/results/bake_fuzz.json: per kind and mode the bits tried, the counts per
outcome, the first few bits of each outcome other than error and same, the most frequent
messages (their first words), and the seconds.
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from provenance import add_output_argument, provenance, write_result  # noqa: E402

KINDS = ("lighting", "object", "view")
SKY_ROWS, SKY_COLUMNS = 32, 64
SCENE = """[render]
width = 16
height = 12
[camera]
eye = [0.0, 2.0, 4.0]
target = [0.0, 0.3, 0.0]
fov_y = 40.0
[environment]
file = "sky.exr"
rotate_y = 15.0
[[objects]]
shape = "sphere"
name = "ball"
translate = [0.0, 0.5, 0.0]
radius = 0.5
subdivisions = 2
material = "m"
[[objects]]
shape = "quad"
size = 6.0
material = "floor"
[materials.m]
type = "ggx"
albedo = [0.9, 0.8, 0.6]
roughness = 0.3
[materials.floor]
type = "lambert"
albedo = [0.6, 0.6, 0.6]
"""

WORKER = r"""
import json, sys, warnings
import numpy as np
sys.path.insert(0, sys.argv[1])
import bake_fuzz
warnings.simplefilter("ignore")
folder, kind = sys.argv[2], sys.argv[3]
bits = [tuple(x.split(":")) for x in sys.argv[4].split(",")]
reader = bake_fuzz.Reader(folder, kind)
for mode, bit in bits:
    print(json.dumps([mode, int(bit), *reader.outcome(mode, int(bit))]), flush=True)
"""


def make_bakes(folder: str, kinds) -> None:
    """The scene, its map and the bakes of ``kinds`` in ``folder``."""
    import numpy as np

    import wavlight

    sky = (np.linspace(1.5, 0.3, SKY_ROWS)[:, None, None] * np.ones((SKY_ROWS, SKY_COLUMNS, 3))).astype(np.float32)
    sky[8, 20] = 3000.0
    wavlight.save_image(os.path.join(folder, "sky.exr"), sky)
    with open(os.path.join(folder, "scene.toml"), "w") as fh:
        fh.write(SCENE)
    scene = wavlight.load_scene(os.path.join(folder, "scene.toml"))
    settings = {"lighting": dict(spp=2, levels=3, terms=32, priority="area"),
                "object": dict(spp=2, levels=3, terms=32, priority="area", vary="object", object="ball",
                               static_spp=4),
                "view": dict(vary="view", levels=3, density=30.0)}
    for kind in kinds:
        wavlight.bake(scene, os.path.join(folder, f"{kind}.wlt"), **settings[kind]).close()


class Reader:
    """A worker's frames of one bake kind: the unmodified file's frames and each flip's outcome."""

    def __init__(self, folder: str, kind: str):
        import numpy as np

        from wavlight.relight import store

        self.np, self.store = np, store
        self.folder, self.kind = folder, kind
        self.src = os.path.join(folder, f"{kind}.wlt")
        with open(self.src, "rb") as fh:
            self.raw = fh.read()
        self.path = os.path.join(folder, f"flipped-{kind}-{os.getpid()}.wlt")
        self.header = store.read_header(self.src)
        self.data_offset = self.header["data_offset"]
        self.reference = {mode: self.frame(self.src, mode) for mode in ("raw", "signed")}

    def frame(self, path, mode):
        """The frame of the bake file ``path`` (the file's defaults for ``raw``, explicit settings
        for ``signed``)."""
        from wavlight.relight import Transfer
        from wavlight.relight.moving import MovingObject
        from wavlight.relight.view_frames import ViewFrames

        tr = Transfer.load(path)
        try:
            if self.kind == "lighting":
                return tr.frame() if mode == "raw" else tr.frame(rotate_y=40.0, terms=32, priority="area")
            if self.kind == "object":
                return MovingObject(tr).frame((0.3, 0.5, 0.0), [0.0, 1.0, 0.0, 20.0], spp=1, seed=0).image
            return ViewFrames(tr).frame(eye=[1.0, 2.0, 3.0], target=[0.0, 0.3, 0.0], fov=40.0, width=16,
                                        height=12, mode="point")[0]
        finally:
            tr.close()

    def flipped(self, mode, bit):
        """The file's bytes with ``bit`` flipped (signed: in the header's text, the checksum signed
        anew, the text's length written anew), or None where a signed flip leaves no JSON object
        with a checksum to sign (or one that outgrows the header's room)."""
        import json as _json
        import zlib

        raw, n = self.raw, len(self.store.MAGIC) + 8
        if mode == "raw":
            b = bytearray(raw)
            b[bit >> 3] ^= 1 << (bit & 7)
            return bytes(b)
        length = int.from_bytes(raw[len(self.store.MAGIC):n], "little")
        if mode == "section":   # a bit of the sections' bytes, that section's CRC-32 signed anew
            data = bytearray(raw)
            data[self.data_offset + (bit >> 3)] ^= 1 << (bit & 7)
            header = _json.loads(raw[n:n + length])
            for meta in header["sections"].values():   # sections, not bytes
                if meta["offset"] <= bit >> 3 < meta["offset"] + meta["bytes"]:
                    at = self.data_offset + meta["offset"]
                    meta["crc32"] = zlib.crc32(bytes(data[at:at + meta["bytes"]]))
            raw = bytes(data)
        else:
            text = bytearray(raw[n:n + length])
            text[bit >> 3] ^= 1 << (bit & 7)
            try:
                header = _json.loads(bytes(text))
            except (ValueError, RecursionError):
                return None
        if not isinstance(header, dict) or "header_crc32" not in header:
            return None
        header["header_crc32"] = self.store.header_checksum(header)
        again = _json.dumps(header).encode()
        room = self.data_offset - n   # the header's text and its padding
        if len(again) > room:
            return None
        return (raw[:len(self.store.MAGIC)] + len(again).to_bytes(8, "little") + again
                + bytes(room - len(again)) + raw[self.data_offset:])

    def outcome(self, mode, bit):
        """(outcome, message's first words or None)."""
        from wavlight.errors import WavlightError

        data = self.flipped(mode, bit)
        if data is None:
            return "not a header to sign", None
        with open(self.path, "wb") as fh:
            fh.write(data)
        try:
            image = self.frame(self.path, mode)
        except WavlightError as e:
            text = str(e)
            if "\n" in text or self.path not in text:
                return "error of another form", text[:200]
            words = text[len(self.path) + 2:].split(":")[0]
            return "error", " ".join(words.split()[:8])
        except Exception as e:   # noqa: BLE001 (what the benchmark counts)
            return type(e).__name__, str(e)[:200]
        reference = self.reference["raw" if mode == "section" else mode]
        if self.np.array_equal(image, reference):
            return "same", None
        if mode == "section":
            return ("finite" if self.np.all(self.np.isfinite(image)) else "a frame of NaN or Inf"), None
        return "another frame", None


def header_bits(path: str) -> int:
    from wavlight.relight import store

    with open(path, "rb") as fh:
        start = fh.read(len(store.MAGIC) + 8)
    return 8 * (len(start) + int.from_bytes(start[len(store.MAGIC):], "little"))


def run_kind(folder: str, kind: str, section_flips: int, batch: int = 2000) -> dict:
    """Every raw and signed flip of the header of the bake of ``kind``, and ``section_flips``
    bits of each section, in worker processes: per mode the counts of outcomes, examples and
    messages."""
    import numpy as np

    from wavlight.relight import store

    path = os.path.join(folder, f"{kind}.wlt")
    bits = header_bits(path)
    prefix = 8 * (len(store.MAGIC) + 8)
    todo = [("raw", b) for b in range(bits)] + [("signed", b) for b in range(bits - prefix)]
    rng = np.random.default_rng(7)
    for meta in store.read_header(path)["sections"].values():   # sections, not bits
        if meta["bytes"]:
            todo += [("section", 8 * meta["offset"] + int(b))
                     for b in rng.choice(8 * meta["bytes"], min(section_flips, 8 * meta["bytes"]), replace=False)]
    results = {}
    t0 = time.perf_counter()
    while todo:
        chunk, todo = todo[:batch], todo[batch:]
        p = subprocess.Popen([sys.executable, "-c", WORKER, HERE, folder, kind,
                              ",".join(f"{m}:{b}" for m, b in chunk)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, cwd=folder)
        out, err = p.communicate()
        done = 0
        for line in out.splitlines():
            mode, bit, what, message = json.loads(line)
            results[(mode, bit)] = (what, message)
            done += 1
        if done < len(chunk):   # the worker died at chunk[done]
            mode, bit = chunk[done]
            tail = err.strip().splitlines()[-1][:200] if err.strip() else ""
            results[(mode, bit)] = (f"crash (exit {p.returncode})", tail)
            todo = chunk[done + 1:] + todo
        print(f"{kind}: {len(results)} flips, {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    summary = {}
    for mode in ("raw", "signed", "section"):
        rows = {bit: v for (m, bit), v in results.items() if m == mode}
        counts = collections.Counter(what for what, _ in rows.values())
        messages = collections.Counter(msg for what, msg in rows.values() if what == "error" and msg)
        other = collections.defaultdict(list)
        for bit, (what, msg) in sorted(rows.items()):
            if what not in ("error", "same", "finite", "not a header to sign") and len(other[what]) < 8:
                other[what].append({"bit": bit, "byte": bit >> 3, "message": msg})
        summary[mode] = {"bits": len(rows), "outcomes": dict(counts.most_common()),
                         "messages": dict(messages.most_common(12)), "failures": dict(other)}
    summary["header_bits"] = bits
    summary["seconds"] = round(time.perf_counter() - t0, 1)
    return summary


def run_cli(folder: str, count: int) -> dict:
    """``count`` evenly spaced raw flips of the lighting bake through ``wavlight frame``: exit
    codes, and whether each refusal is one ``Error:`` line."""
    exe = os.path.join(os.path.dirname(sys.executable), "wavlight")
    command = [exe] if os.path.isfile(exe) else [sys.executable, "-m", "wavlight.cli.main"]
    src = os.path.join(folder, "lighting.wlt")
    with open(src, "rb") as fh:
        raw = fh.read()
    bits = header_bits(src)
    codes, shapes = collections.Counter(), collections.Counter()
    path, out = os.path.join(folder, "cli.wlt"), os.path.join(folder, "cli.png")
    for bit in [int(i * bits / count) for i in range(count)]:
        b = bytearray(raw)
        b[bit >> 3] ^= 1 << (bit & 7)
        with open(path, "wb") as fh:
            fh.write(b)
        p = subprocess.run(command + ["frame", path, "-o", out], capture_output=True, text=True, timeout=600,
                           cwd=folder)
        codes[p.returncode] += 1
        lines = [ln for ln in p.stderr.splitlines() if ln.strip() and not ln.startswith(("note:", "warning:"))]
        if p.returncode == 2:
            shapes["one Error: line" if len(lines) == 1 and lines[0].startswith("Error: ") else "other"] += 1
    return {"flips": count, "exit_codes": {str(k): v for k, v in codes.items()}, "refusals": dict(shapes)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kinds", default=",".join(KINDS), help="bake kinds (lighting, object, view)")
    parser.add_argument("--cli", type=int, default=64, help="raw flips of the lighting bake through the CLI")
    parser.add_argument("--section-flips", type=int, default=64, help="bits flipped in each section")
    parser.add_argument("--compare", default=None, help="a result file of another run, kept under 'compared'")
    add_output_argument(parser, "bake_fuzz")
    args = parser.parse_args()
    kinds = [k for k in args.kinds.split(",") if k]
    if not set(kinds) <= set(KINDS):
        parser.error(f"--kinds: one or more of {', '.join(KINDS)}")
    prov = provenance()
    with tempfile.TemporaryDirectory(prefix="bake-fuzz-") as folder:
        t0 = time.perf_counter()
        make_bakes(folder, kinds)
        data = {"bake_seconds": round(time.perf_counter() - t0, 1),
                "kinds": {kind: run_kind(folder, kind, args.section_flips) for kind in kinds}}
        if args.cli and "lighting" in kinds:
            data["cli"] = run_cli(folder, args.cli)
    print(json.dumps({k: {m: v[m]["outcomes"] for m in ("raw", "signed", "section")} for k, v in data["kinds"].items()},
                     indent=1))
    if args.compare:
        with open(args.compare) as fh:
            other = json.load(fh)
        data["compared"] = {"wavlight": other["provenance"].get("wavlight"), "command": other["provenance"]["command"],
                            "kinds": {k: {"header_bits": v["header_bits"],
                                          **{m: v[m]["outcomes"] for m in ("raw", "signed", "section")}}
                                      for k, v in other["kinds"].items()}}
    write_result(args.output, data, prov)


if __name__ == "__main__":
    main()
