"""Where a benchmark figure comes from, and the one place each benchmark writes it.

Every script in benchmarks/ writes one current result file, ``benchmarks/results/<name>.json``,
through :func:`write_result`: ``{"provenance": provenance(), **data}``. Running a benchmark
again replaces its file. :func:`provenance` records

- ``commit``: ``git rev-parse HEAD`` of the checkout, and ``dirty``: whether
  ``git status --porcelain`` shows changes to tracked files (the figures then belong to
  the work tree, not to the commit alone);
- ``cpu`` (the model name in /proc/cpuinfo, else ``platform.processor()``), ``cores``
  (``os.cpu_count()``) and ``isa`` (the vector extensions among the CPU's flags);
- ``opencl``: the platform (name, version) and device (name, driver version) of the
  device wavlight renders on (``wavlight.cl.runtime()``);
- ``python``, ``numpy`` and ``wavlight`` versions;
- ``command``: the command line as run from the repository's root, e.g.
  ``python benchmarks/render_bench.py --spp 16`` (the interpreter's path left out);
- ``load_average``: the 1, 5 and 15 minute load averages when the run started, and
  ``load_average_end`` when the result was written (on a shared 2-core machine a load
  above 1 slows the timing benchmarks);
- ``utc``: when the run started (ISO 8601).

    from provenance import provenance, write_result   # (benchmarks/ is on the path)
    prov = provenance()            # at the start of the run
    ...
    write_result("render_bench", data, prov)   # -> benchmarks/results/render_bench.json
"""
from __future__ import annotations

import datetime
import json
import os
import platform
import shlex
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
RESULTS = os.path.join(HERE, "results")
#: vector extensions worth knowing for the kernels' speed (PoCL compiles for the host CPU)
ISA_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512bw", "avx512vl")


def _git(*args: str) -> str | None:
    try:
        res = subprocess.run(["git", "-C", ROOT, *args], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return res.stdout if res.returncode == 0 else None


def _cpu() -> tuple[str, list[str]]:
    model, flags = "", []
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                key = key.strip()
                if key == "model name" and not model:
                    model = value.strip()
                elif key == "flags" and not flags:
                    have = set(value.split())
                    flags = [f for f in ISA_FLAGS if f in have]
                if model and flags:
                    break
    except OSError:
        pass
    return model or platform.processor() or platform.machine(), flags


def _opencl_here() -> dict:
    from wavlight import cl

    dev = cl.runtime().device
    return {"platform": dev.platform.name.strip(), "platform_version": dev.platform.version.strip(),
            "device": dev.name.strip(), "driver_version": dev.driver_version.strip()}


def _opencl_in_subprocess() -> dict:
    """The same, asked of a fresh interpreter (for a process that must not load PoCL's LLVM
    beside another one, as Mitsuba's)."""
    code = ("import json, sys; sys.path.insert(0, %r); import provenance; "
            "print(json.dumps(provenance._opencl_here()))" % HERE)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    if res.returncode != 0:
        return {"error": (res.stderr.strip().splitlines() or ["failed"])[-1]}
    return json.loads(res.stdout.strip().splitlines()[-1])


def _wavlight_version() -> str | None:
    """wavlight/version.py's __version__, read without importing wavlight (mitsuba_peer.py
    runs without it)."""
    try:
        with open(os.path.join(ROOT, "wavlight", "version.py")) as fh:
            for line in fh:
                if line.startswith("__version__"):
                    return line.split("=", 1)[1].strip().strip("\"'")
    except OSError:
        pass
    return None


def command_line(argv: list[str] | None = None) -> str:
    """The command as typed at the repository's root: ``python benchmarks/x.py ARGS``."""
    argv = list(sys.argv if argv is None else argv)
    script = os.path.abspath(argv[0]) if argv and argv[0] not in ("", "-c") else ""
    if script:
        rel = os.path.relpath(script, ROOT)
        argv[0] = rel if not rel.startswith("..") else script
    return shlex.join(["python", *argv])


def provenance(opencl: str = "here") -> dict:
    """The run's provenance (see the module notes). opencl: "here" asks wavlight.cl in this
    process, "subprocess" in a fresh interpreter, "none" leaves it out (recorded as null)."""
    import numpy

    commit = (_git("rev-parse", "HEAD") or "").strip() or None
    status = _git("status", "--porcelain", "--untracked-files=no")
    cpu, isa = _cpu()
    if opencl == "here":
        try:
            cl_info = _opencl_here()
        except Exception as e:  # record, do not hide: a benchmark may not need the device
            cl_info = {"error": f"{type(e).__name__}: {e}"}
    elif opencl == "subprocess":
        cl_info = _opencl_in_subprocess()
    else:
        cl_info = None
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = None
    return {"commit": commit, "dirty": bool(status.strip()) if status is not None else None,
            "cpu": cpu, "cores": os.cpu_count(), "isa": isa, "opencl": cl_info,
            "python": platform.python_version(), "numpy": numpy.__version__, "wavlight": _wavlight_version(),
            "command": command_line(), "load_average": load,
            "utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}


def result_path(name: str) -> str:
    """benchmarks/results/<name>.json"""
    return os.path.join(RESULTS, f"{name}.json")


def add_output_argument(parser, name: str) -> None:
    """-o/--output FILE (default benchmarks/results/<name>.json; "-" writes no file)."""
    parser.add_argument("-o", "--output", default=result_path(name), metavar="FILE",
                        help=f"result file (default benchmarks/results/{name}.json; '-': none, stdout only)")


def write_result(name_or_path: str, data: dict, prov: dict | None = None) -> str | None:
    """Write ``{"provenance": prov, **data}`` to benchmarks/results/<name>.json (or to the
    path given, one with a folder or ending in .json; "-" writes nothing), atomically: a temporary file in
    the same folder renamed over the old one. Returns the path written."""
    if name_or_path == "-":
        return None
    is_path = name_or_path.endswith(".json") or os.sep in name_or_path
    path = name_or_path if is_path else result_path(name_or_path)
    path = os.path.abspath(path)
    folder = os.path.dirname(path)
    os.makedirs(folder, exist_ok=True)
    prov = dict(prov) if prov is not None else provenance()
    try:   # the load when the run ended, beside the load when it started
        prov["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        pass
    body = {"provenance": prov, **data}
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".json", dir=folder)
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(body, fh, indent=1)
            fh.write("\n")
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    print(f"wrote {os.path.relpath(path, ROOT) if path.startswith(ROOT) else path}", file=sys.stderr)
    return path
