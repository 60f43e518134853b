"""Time to the first render, cold and warm, on each OpenCL route; and what each route installs.

A newcomer's first command after the install is a render of the built-in scene. Its time is
mostly the kernels' compilation the first time (cold: empty kernel caches, PoCL's and
wavlight's, in a fresh ``XDG_CACHE_HOME``) and start-up afterwards (warm: the same caches
again). Routes, each run as a whole ``wavlight render`` process and alternated run by run
(this machine drifts 20-40% between runs):

- ``pocl``: the PoCL that pyopencl's wheel carries (``WAVLIGHT_CL_DEVICE=Portable``);
- ``intel``: Intel's OpenCL CPU runtime from PyPI (``WAVLIGHT_CL_DEVICE=Intel``), the fallback
  where that PoCL cannot compile for the CPU, with wavlight's settings for it;
- ``intel-vectorizer`` (cold only): the same with Intel's implicit vectorizer on
  (``CL_CONFIG_USE_VECTORIZER=True``), the setting wavlight turns off.

Install sizes are the bytes of each installed distribution's files (importlib.metadata).
Writes benchmarks/results/first_render.json.

    python benchmarks/first_render.py --runs 3
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from importlib import metadata

from provenance import ROOT, provenance, write_result

WAVLIGHT = os.path.join(os.path.dirname(sys.executable), "wavlight")
ROUTES = {"pocl": {"WAVLIGHT_CL_DEVICE": "Portable"},
          "intel": {"WAVLIGHT_CL_DEVICE": "Intel"},
          "intel-vectorizer": {"WAVLIGHT_CL_DEVICE": "Intel", "CL_CONFIG_USE_VECTORIZER": "True"}}
INTEL = ("intel-opencl-rt", "intel-cmplr-lib-rt", "intel-cmplr-lic-rt", "tbb", "tcmlib")


def distribution_bytes(name: str) -> int:
    try:
        dist = metadata.distribution(name)
    except metadata.PackageNotFoundError:
        return 0
    total = 0
    for f in dist.files or ():
        try:
            total += os.path.getsize(dist.locate_file(f))
        except OSError:
            pass
    return total


def environment_bytes() -> int:
    return sum(distribution_bytes(d.metadata["Name"]) for d in metadata.distributions())


def render_once(scene: str, env: dict, out: str) -> dict:
    t0 = time.perf_counter()
    r = subprocess.run([WAVLIGHT, "render", scene, "-o", out, "--json"], capture_output=True, text=True,
                       env=env, cwd=ROOT, timeout=1800)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        return {"error": (r.stderr.strip().splitlines() or ["failed"])[-1]}
    stats = json.loads(r.stdout)
    return {"seconds": round(wall, 2), "render_seconds": stats["render_seconds"],
            "setup_seconds": stats["setup_seconds"],
            "compiled": "compiling OpenCL kernels" in r.stderr}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--scene", default="scenes/default.toml")
    args = ap.parse_args()
    prov = provenance(opencl="none")
    runs = {name: [] for name in ROUTES}
    for i in range(args.runs):
        for name, extra in ROUTES.items():
            with tempfile.TemporaryDirectory() as tmp:
                env = {k: v for k, v in os.environ.items()
                       if k not in ("CL_CONFIG_USE_VECTORIZER", "WAVLIGHT_CL_DEVICE")}
                env.update(XDG_CACHE_HOME=os.path.join(tmp, "cache"), POCL_CACHE_DIR=os.path.join(tmp, "pocl"), **extra)
                out = os.path.join(tmp, "first.png")
                cold = render_once(args.scene, env, out)
                warm = None if name == "intel-vectorizer" else render_once(args.scene, env, out)
            runs[name].append({"cold": cold, "warm": warm})
            print(f"run {i} {name}: cold {cold} warm {warm}", file=sys.stderr)

    def median(name, kind):
        xs = sorted(r[kind]["seconds"] for r in runs[name] if r[kind] and "seconds" in r[kind])
        return xs[len(xs) // 2] if xs else None

    sizes = {name: distribution_bytes(name) for name in ("pyopencl", "pocl-binary-distribution", *INTEL)}
    data = {"scene": args.scene, "runs": runs,
            "median_seconds": {name: {"cold": median(name, "cold"), "warm": median(name, "warm")} for name in ROUTES},
            "install_bytes": {"environment": environment_bytes(), **sizes,
                              "intel_runtime_total": sum(sizes[n] for n in INTEL)}}
    write_result("first_render", data, prov)
    print(json.dumps(data["median_seconds"]), json.dumps(data["install_bytes"]))


if __name__ == "__main__":
    main()
