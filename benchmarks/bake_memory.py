"""What loading a bake file costs: memory and time, and frames from a file truncated under them
(docs/decisions/bake-file-mapping.md).

Each bake file given is loaded in a fresh child process (``wavlight.Transfer.load``), which then
makes ``--frames`` frames turned by 10 degrees each; the child reports its resident memory
(``VmRSS``, and of it ``RssAnon``: memory of its own, ``RssFile``: pages of files it maps, which
the kernel may drop and read again) before loading, after loading and after the frames, its
peak (``VmHWM``), and the seconds of the load and of a frame. A second child loads the file,
makes a frame, truncates a copy of the file under it and makes another frame: ``truncated``
says whether it went on (``ok``) or how it ended (a signal: SIGBUS is -7).

    python benchmarks/bake_memory.py BAKE.wlt [BAKE.wlt ...] [--frames 5] [--tree DIR] [--compare FILE]
                                     [-o FILE]

``--tree DIR`` runs the children with PYTHONPATH=DIR, to measure another copy of the package
(one that maps the file, for instance: a checkout's wavlight/ with kernels/ copied into it as
wavlight/kernels and cli/ as wavlight/cli); ``--compare FILE`` keeps the rows of such a run
under ``compared``. Writes benchmarks/results/bake_memory.json.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from provenance import add_output_argument, provenance, write_result  # noqa: E402

LOAD = r"""
import json, sys, time
import wavlight

def memory():
    out = {}
    with open("/proc/self/status") as fh:
        for line in fh:
            key = line.split(":")[0]
            if key in ("VmRSS", "RssAnon", "RssFile", "VmHWM"):
                out[key] = round(int(line.split()[1]) / 1024, 1)
    return out

path, frames = sys.argv[1], int(sys.argv[2])
before = memory()
t = time.perf_counter()
tr = wavlight.Transfer.load(path)
load = time.perf_counter() - t
loaded = memory()
seconds = []
for i in range(frames):
    t = time.perf_counter()
    tr.frame(rotate_y=10.0 * i)
    seconds.append(time.perf_counter() - t)
print(json.dumps({"before_mb": before, "loaded_mb": loaded, "after_frames_mb": memory(),
                  "load_seconds": round(load, 3), "frame_seconds": round(sorted(seconds)[len(seconds) // 2], 4)}))
"""

TRUNCATE = r"""
import os, sys
import wavlight
path = sys.argv[1]
tr = wavlight.Transfer.load(path)
tr.frame(rotate_y=0.0)
os.truncate(path, 4096)
tr.frame(rotate_y=10.0)
print("ok")
"""


def child(code, args, env):
    p = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, env=env,
                       cwd=tempfile.gettempdir(), timeout=3600)
    return p.returncode, p.stdout.strip().splitlines()[-1] if p.stdout.strip() else "", p.stderr.strip()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("bakes", nargs="+", help="bake files")
    parser.add_argument("--frames", type=int, default=5)
    parser.add_argument("--tree", default=None, help="run the children with PYTHONPATH=DIR")
    parser.add_argument("--compare", default=None, help="a result file of another run, kept under 'compared'")
    add_output_argument(parser, "bake_memory")
    args = parser.parse_args()
    env = dict(os.environ, **({"PYTHONPATH": args.tree} if args.tree else {}))
    prov = provenance()
    rows = []
    for path in args.bakes:
        code, out, err = child(LOAD, [os.path.abspath(path), args.frames], env)
        row = {"file": os.path.basename(path), "file_mb": round(os.path.getsize(path) / 2 ** 20, 1)}
        row.update(json.loads(out) if code == 0 else {"error": (err.splitlines() or [""])[-1][:200]})
        with tempfile.TemporaryDirectory() as folder:
            copy = os.path.join(folder, "copy.wlt")
            shutil.copyfile(path, copy)
            code, out, err = child(TRUNCATE, [copy], env)
        row["truncated"] = "ok" if code == 0 and out == "ok" else f"exit {code}"
        rows.append(row)
        print(json.dumps(row), flush=True)
    data = {"tree": args.tree or "this checkout", "rows": rows}
    if args.compare:
        with open(args.compare) as fh:
            other = json.load(fh)
        data["compared"] = {"tree": other.get("tree"), "commit": other["provenance"].get("commit"),
                            "rows": other["rows"]}
    write_result(args.output, data, prov)


if __name__ == "__main__":
    main()
