"""Slow probes of hostile input: peak memory against image size (PNG and EXR), and the time bad
input takes to be refused.

**Memory.** Each row is one `wavlight render` of a map-only scene (the procedural sky, no
objects: the film and the writer dominate) at W x W pixels and 1 spp in a fresh child process;
``peak_mb`` is the child's peak resident set (``os.wait4``'s ru_maxrss) and ``bytes_per_pixel``
its excess over a 64 x 64 render's (the ``base`` row: Python, numpy, OpenCL) per pixel. ``write`` rows are a
child that allocates a random float32 (W, W, 3) image and saves it: ``write_bytes_per_pixel``
is its peak minus the peak before the write, per pixel (the writer's own cost: the strip
writer keeps it to a few MiB in all, where writing a PNG whole costs about 50 bytes per pixel).
``--tree DIR`` runs the children with PYTHONPATH=DIR, to measure another copy of the package.

**Time to refuse.** Each row is a child given bad input; ``seconds`` is its wall time to a
one-line refusal (exit 2) and ``peak_mb`` its memory. Every child runs with a 6 GB
address-space limit and a 120 s timeout, so that input that is not refused early ends in a
bounded failure instead of filling the machine.

    python benchmarks/probe_memory.py [--sizes 1024,2048,4096,8192] [--formats png,exr]
                                      [--refusals | --no-refusals] [--tree DIR] [--compare FILE] [-o FILE]

The committed figures hold this checkout's rows and, under ``compared``, those of a baseline
copy of the package given with --tree (wavlight/ with imageio, meshes, envmap, errors, raytrace
and evaluation/{experiment,records,charts,stability}.py that write images whole and check
input only where it is used):

    python benchmarks/probe_memory.py --tree /tmp/wl-baseline -o /tmp/probe-baseline.json
    python benchmarks/probe_memory.py --compare /tmp/probe-baseline.json

Writes benchmarks/results/probe-memory.json (``-o -``: stdout only).
"""
from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

SKY = ('render = { width = 64, height = 64, spp = 1 }\n'
       'camera = { eye = [0.0, 1.0, 3.0], target = [0.0, 0.4, 0.0] }\n'
       'environment = { procedural = "sky" }\n')

WRITE = r"""
import resource, sys, numpy as np, wavlight
n, path = int(sys.argv[1]), sys.argv[2]
img = np.random.default_rng(0).random((n, n, 3), dtype=np.float32)
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t = __import__("time").perf_counter()
wavlight.save_image(path, img)
print(before, __import__("time").perf_counter() - t)
"""

LIMITED = r"""
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (6 << 30, 6 << 30))
from wavlight.cli.main import main
sys.argv = ["wavlight"] + sys.argv[1:]
main()
"""


def child(args, env, timeout=1800, cwd=None):
    """(returncode, stdout, stderr, seconds, peak RSS MB) of a child process, run in a temporary
    folder (with ``-c`` the working folder comes first on sys.path: in the checkout it would
    shadow --tree)."""
    cwd = cwd or tempfile.gettempdir()
    t = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        p = subprocess.Popen(args, stdout=out, stderr=err, env=env, cwd=cwd, text=True)
        deadline = time.monotonic() + timeout
        while True:
            pid, status, usage = os.wait4(p.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() > deadline:
                p.kill()
                pid, status, usage = os.wait4(p.pid, 0)
                status = -1
                break
            time.sleep(0.05)
        seconds = time.perf_counter() - t
        p.returncode = os.waitstatus_to_exitcode(status) if status != -1 else "timeout"
        out.seek(0)
        err.seek(0)
        return p.returncode, out.read(), err.read(), round(seconds, 2), round(usage.ru_maxrss / 1024, 1)


def wavlight_cmd():
    exe = os.path.join(os.path.dirname(sys.executable), "wavlight")
    return [exe] if os.path.isfile(exe) else [sys.executable, "-m", "wavlight.cli.main"]


def memory_rows(sizes, formats, env, folder):
    scene = os.path.join(folder, "sky.toml")
    with open(scene, "w") as fh:
        fh.write(SKY)
    rows = []
    code, _, err, _, base = child(wavlight_cmd() + ["render", scene, "-o", os.path.join(folder, "base.exr"), "-q"], env)
    rows.append({"kind": "base", "size": 64, "exit": code, "peak_mb": base})
    print(json.dumps(rows[-1]), flush=True)
    for n in sizes:
        for fmt in formats:
            out = os.path.join(folder, f"o.{fmt}")
            code, _, err, seconds, peak = child(wavlight_cmd() + ["render", scene, "-o", out, "--width", str(n),
                                                                  "--height", str(n), "--spp", "1", "-q"], env)
            row = {"kind": "render", "size": n, "format": fmt, "pixels": n * n, "exit": code, "seconds": seconds,
                   "peak_mb": peak, "bytes_per_pixel": round((peak - base) * 2 ** 20 / (n * n), 1)}
            if code != 0:
                row["error"] = err.strip().splitlines()[-1][:200] if err.strip() else ""
            rows.append(row)
            print(json.dumps(row), flush=True)
            code, stdout, err, seconds, peak = child([sys.executable, "-c", WRITE, str(n), out], env)
            row = {"kind": "write", "size": n, "format": fmt, "pixels": n * n, "exit": code, "peak_mb": peak}
            if code == 0:
                before_kb, write_s = stdout.split()
                row["write_seconds"] = round(float(write_s), 2)
                row["write_bytes_per_pixel"] = round((peak * 1024 - float(before_kb)) * 1024 / (n * n), 1)
            rows.append(row)
            print(json.dumps(row), flush=True)
            if os.path.exists(out):
                os.unlink(out)
    return rows


class _Silent:
    """127.0.0.1 server that accepts and never answers (stops after `seconds`)."""

    def __init__(self, reply=b"", seconds=120):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.sock.settimeout(0.2)
        self.address = f"tcp://127.0.0.1:{self.sock.getsockname()[1]}"
        self.reply, self.end, self.conns = reply, time.monotonic() + seconds, []
        threading.Thread(target=self.serve, daemon=True).start()

    def serve(self):
        while time.monotonic() < self.end:
            try:
                c, _ = self.sock.accept()
            except OSError:
                continue
            self.conns.append(c)
            if self.reply:
                try:
                    c.sendall(self.reply)
                except OSError:
                    pass
        for c in self.conns:
            c.close()
        self.sock.close()


def refusal_rows(env, folder):
    """Bad input, each refused in one line: wall time and peak memory to the refusal."""
    def write(name, text):
        path = os.path.join(folder, name)
        with open(path, "w") as fh:
            fh.write(text)
        return path

    sky = write("sc.toml", SKY)
    cases = []
    spec = write("reps.toml", f'[reference]\nspp = 4\nseed = 1000000000\n[[scenes]]\npath = "{sky}"\n'
                              '[[strategies]]\nid = "mis"\n[budgets]\nspp = [1]\nrepetitions = 100000000\n')
    cases.append(("experiment of 10^8 repetitions", ["experiment", spec, "-o", os.path.join(folder, "o1"), "-q"]))
    ref = os.path.join(folder, "ref.pfm")
    with open(ref, "wb") as fh:
        fh.write(b"PF\n64 63\n-1.0\n" + b"\0" * (64 * 63 * 12))
    spec = write("late.toml", f'[experiment]\nsize = [64, 64]\n[reference]\nspp = 4\nseed = 1000000000\n'
                              f'[[scenes]]\npath = "{sky}"\n[[scenes]]\npath = "{sky}"\nname = "two"\n'
                              f'reference = "{ref}"\n[[strategies]]\nid = "mis"\n[budgets]\nspp = [1]\n'
                              'repetitions = 100000\n')
    cases.append(("second scene's reference of the wrong size, 10^5 repetitions",
                  ["experiment", spec, "-o", os.path.join(folder, "o2"), "-q"]))
    big = os.path.join(folder, "big.pfm")
    with open(big, "wb") as fh:
        fh.write(b"PF\n20000 20000\n-1.0\n")
        fh.truncate(fh.tell() + 20000 * 20000 * 12)
    cases.append(("map header of 20000 x 20000 (sparse file)",
                  ["render", write("bigmap.toml", SKY.replace('procedural = "sky"', f'file = "{big}"')),
                   "-o", os.path.join(folder, "o.png")]))
    mesh = os.path.join(folder, "huge.ply")
    with open(mesh, "wb") as fh:
        fh.truncate(3 << 30)
    cases.append(("sparse 3 GB PLY", ["render", write("mesh.toml", SKY + f'[[objects]]\nmesh = "{mesh}"\n'),
                                      "-o", os.path.join(folder, "o.png")]))
    cases.append(("100 spheres of subdivisions 8", ["render", write("spheres.toml", SKY + '[[objects]]\nshape = "sphere"\n'
                                                                    'subdivisions = 8\n' * 100),
                                                    "-o", os.path.join(folder, "o.png")]))
    cases.append(("TOML nested 1000 deep", ["render", write("deep.toml", "x = " + "[" * 1000 + "]" * 1000 + "\n"),
                                            "-o", os.path.join(folder, "o.png")]))
    cases.append(("a 10 MB array value", ["render", write("long.toml", SKY.replace(
        "eye = [0.0, 1.0, 3.0]", "eye = [" + ", ".join(["1.0"] * 2_000_000) + "]")), "-o", os.path.join(folder, "o.png")]))
    cases.append(("100 001 objects, a bad key on the last", ["render", write("many.toml", SKY + '[[objects]]\nshape = "sphere"\n'
                                                                              'subdivisions = 1\n' * 100_000 +
                                                                              '[[objects]]\nshape = "quad"\ncolour = 1\n'),
                                                             "-o", os.path.join(folder, "o.png")]))
    spec = write("dask.toml", f'[reference]\nspp = 4\n[[scenes]]\npath = "{sky}"\n[[strategies]]\nid = "mis"\n'
                              '[budgets]\nspp = [1]\n')
    servers = {"silent": lambda: _Silent(), "http": lambda: _Silent(b"HTTP/1.1 200 OK\r\nContent-Length: 5\r\n\r\nhello")}
    cases.append(("--dask at a service that never answers", ["experiment", spec, "-o", os.path.join(folder, "o3"),
                                                            "-q", "--dask", "silent"]))
    cases.append(("--dask at an HTTP server", ["experiment", spec, "-o", os.path.join(folder, "o4"), "-q",
                                              "--dask", "http"]))
    rows = []
    for name, argv in cases:
        if argv[-1] in servers:   # started just before its case (it stops by itself after 120 s)
            argv = argv[:-1] + [servers[argv[-1]]().address]
        code, _, err, seconds, peak = child([sys.executable, "-c", LIMITED] + argv, env, timeout=120)
        lines = [line for line in err.splitlines() if line.strip()]
        row = {"case": name, "exit": code, "seconds": seconds, "peak_mb": peak,
               "one_line": code == 2 and len(lines) == 1 and lines[0].startswith("Error:"),
               "message": (lines[-1][:160] if lines else "")}
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="1024,2048,4096,8192")
    ap.add_argument("--formats", default="png,exr")
    ap.add_argument("--refusals", action=argparse.BooleanOptionalAction, default=True)
    ap.add_argument("--tree", default=None, help="run the children with PYTHONPATH=TREE (another copy of wavlight/)")
    ap.add_argument("--compare", default=None, metavar="FILE",
                    help="a result file of another run (say one with --tree at a baseline copy), kept under "
                         "'compared' in this one")
    from provenance import add_output_argument, provenance, write_result

    add_output_argument(ap, "probe-memory")
    args = ap.parse_args()
    prov = provenance()
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    if args.tree:
        env["PYTHONPATH"] = os.path.abspath(args.tree)
    sizes = [int(x) for x in args.sizes.split(",") if x]
    with tempfile.TemporaryDirectory(prefix="wavlight-probe-") as folder:
        data = {"tree": args.tree or "this checkout",
                "memory": memory_rows(sizes, args.formats.split(","), env, folder) if sizes else [],
                "refusals": refusal_rows(env, folder) if args.refusals else []}
    if args.compare:
        with open(args.compare) as fh:
            other = json.load(fh)
        data["compared"] = {k: other.get(k) for k in ("tree", "memory", "refusals")}
    path = write_result(args.output, data, prov)
    if not path:
        print(json.dumps(data))


if __name__ == "__main__":
    main()
