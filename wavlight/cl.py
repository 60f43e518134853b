"""OpenCL device choice, kernel sources and the per-process program cache.

Device choice
-------------
By default wavlight uses the first PoCL CPU device that can actually build a
program, else the first other device that can. The probe build matters: the PoCL
bundled with the PyPI wheels links LLVM 14, which does not know CPUs newer than it
(AMD Zen 5 reports "unknown target CPU 'generic'"). On Linux x86-64 pip also
installs Intel's OpenCL CPU runtime, which :mod:`wavlight.icd` makes known to the
ICD loader; it runs the same kernels where that PoCL cannot
(docs/decisions/opencl-fallback.md). A system PoCL (Debian's ``pocl-opencl-icd``)
or any other driver is picked up too. :attr:`Runtime.reason` says why the device
in use was chosen (``wavlight info`` prints it).

``WAVLIGHT_CL_DEVICE`` overrides the choice: ``"P:D"`` (platform and device
indices as ``wavlight info`` lists them) or any text that occurs in
"platform name + platform version + device name" (case-insensitive), e.g. ``"NVIDIA"``,
``"PoCL"``, ``"Intel"``.
On PoCL CPU devices the kernels use kernels/simd.h's inline equivalents of the
OpenCL builtins (:func:`inline_builtins`); ``WAVLIGHT_INLINE_BUILTINS=0`` or ``1``
overrides that.

Programs
--------
Kernel sources live in the ``kernels/`` folder, installed as the package
``wavlight.kernels``. Local ``#include "x.h"`` lines are spliced on the host
(PoCL has failed on ``-I`` include paths). Each program is built once per
(context, file, defines) and memoised for the life of the process; across
processes the driver's own kernel cache (PoCL's) or wavlight's (the program
binaries of drivers that keep none, in ``~/.cache/wavlight/kernels``) spares the
rebuild, and the first build that is not cached logs one line ("compiling OpenCL
kernels ...", which the command line shows). Kernels that
walk trees are built per tree depth (``-DN_LEVELS``), so that their level loop
unrolls. The per-sample kernels take eight points per work-item in OpenCL vector
types (kernels/simd.h, :data:`LANES`, :func:`items`).
"""
from __future__ import annotations

import functools
import hashlib
import logging
import os
import re
import sys
import threading
from dataclasses import dataclass
from importlib import resources

import numpy as np

from . import icd
from .cache import cache_dir
from .errors import WavlightError

DEVICE_ENV = "WAVLIGHT_CL_DEVICE"
INLINE_ENV = "WAVLIGHT_INLINE_BUILTINS"
# Work-group size of the per-sample kernels (warp, product, shade): PoCL compiles a kernel
# per work-group size on first launch, so one fixed size keeps it to one compile.
WORK_GROUP = 64
# Work-group size of the stand-alone walking kernels with level barriers (warp.cl,
# product.cl; kernels/warp.h): a smaller group keeps what PoCL stores per work-item at each
# barrier in the cache. Measured with benchmarks/kernel_ab.py, BARRIER_LEVEL 8 in groups of 32
# against level 9 in groups of 64 (eight alternated runs, 2^21 random points): light walk 2048^2 55 -> 59 M/s, product walks
# at 2048^2 and 1024^2 +3 to +15%, within 2% at 64^2 and 256^2. A divisor of WORK_GROUP, so
# that items() fits both.
WALK_WORK_GROUP = 32
# Points per work-item of the kernels written in vector types (kernels/simd.h: warp,
# product, shade), passed to every program as -DLANES (8 or 16; 16 measured no faster on
# an AVX2 CPU).
LANES = 8


def items(count: int, lanes: int = 1) -> int:
    """Global size for count points at `lanes` points per work-item, a multiple of WORK_GROUP."""
    groups = -(-max(count, 1) // lanes)
    return -(-groups // WORK_GROUP) * WORK_GROUP


_PROBE_SRC = "__kernel void probe(__global float *a) { a[get_global_id(0)] *= 2.0f; }"


@dataclass(frozen=True)
class Runtime:
    """A context and an in-order queue on one device, and why that device was chosen."""

    context: object
    queue: object
    device: object
    reason: str = ""

    @property
    def description(self) -> str:
        p = self.device.platform
        return f"{p.name} ({p.version.strip()}) / {self.device.name}"


@functools.cache
def _invoker_cache() -> None:
    """pyopencl keeps the code of its kernel invokers in pytools' cache folder (the user cache's
    ``pytools``) and raises from its first kernel where that folder cannot be made (a read-only
    home, an XDG_CACHE_HOME that is a file): there its cache is turned off (PYOPENCL_NO_CACHE,
    read when pyopencl is imported; the invoker is then generated once per kernel object)."""
    if "PYOPENCL_NO_CACHE" in os.environ:
        return
    import platformdirs

    xdg = os.environ.get("XDG_CACHE_HOME")   # pytools' own rule: platformdirs, or XDG_CACHE_HOME on macOS
    folder = (os.path.join(xdg, "pytools") if sys.platform == "darwin" and xdg is not None
              else platformdirs.user_cache_dir("pytools", "pytools"))
    try:
        os.makedirs(folder, exist_ok=True)
        writable = os.access(folder, os.W_OK)
    except OSError:
        writable = False
    if not writable:
        os.environ["PYOPENCL_NO_CACHE"] = "1"


def opencl():
    """pyopencl, with the pip-installed OpenCL drivers registered (wavlight.icd) before the ICD
    loader's first use: pyopencl's import does not use it, the first platform query does; and
    its invoker cache turned off where it cannot be written (:func:`_invoker_cache`)."""
    icd.register()
    _invoker_cache()
    import warnings

    import pyopencl  # deferred: importing it costs ~0.1 s

    # a driver's informational build log ("Compilation started ...") is no warning to the user;
    # a failed build raises with its log (_build)
    warnings.filterwarnings("ignore", category=pyopencl.CompilerWarning)
    return pyopencl


def list_devices():
    """All (platform index, device index, platform, device) tuples."""
    cl = opencl()
    out = []
    try:
        platforms = cl.get_platforms()
    except cl.Error:
        return out
    for pi, p in enumerate(platforms):
        try:
            devs = p.get_devices()
        except cl.Error:
            continue
        for di, d in enumerate(devs):
            out.append((pi, di, p, d))
    return out


def _is_pocl(device) -> bool:
    return "portable" in device.platform.name.lower()


def build_problem(device) -> str | None:
    """None when `device` builds and runs a tiny program, else the driver's reason in one line."""
    cl = opencl()
    try:
        ctx = cl.Context([device])
        prg = cl._cl._Program(ctx, _PROBE_SRC)
        prg.build(b"", None)
        return None
    except Exception as e:  # any build or driver failure disqualifies the device
        text = str(e)
        try:
            text += "\n" + prg.get_build_info(device, cl.program_build_info.LOG)
        except Exception:
            pass
        lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
        for ln in lines:   # the compiler's own words where it gave some ("unknown target CPU 'generic'")
            if "error" in ln.lower() and "build_program_failure" not in ln.lower():
                return ln[:200]
        return (lines[0] if lines else type(e).__name__)[:200]


def _label(device) -> str:
    """A device's name for messages: "PoCL 3.0-rc2 (LLVM 14.0.6) / pthread-AMD EPYC"."""
    version = device.platform.version
    m = re.search(r"(PoCL \S+).*?(LLVM \S+)", version)
    platform = f"{m[1]} ({m[2].rstrip(',')})" if m else device.platform.name.strip()
    return f"{platform} / {device.name.strip()}"


def no_device_advice() -> str:
    """What to install when no OpenCL device can build programs, for this platform."""
    import platform

    machine = platform.machine().lower()
    if sys.platform == "darwin":
        return "macOS provides OpenCL itself; check that the system's OpenCL framework is present"
    if sys.platform.startswith("linux") and machine in ("x86_64", "amd64"):
        return ("reinstall wavlight with pip (it brings PoCL and Intel's OpenCL CPU runtime: "
                "intel-opencl-rt, intel-cmplr-lib-rt), or install a system driver such as Debian's "
                "pocl-opencl-icd")
    return "install an OpenCL driver for this machine, e.g. Debian's pocl-opencl-icd"


def _pick_device():
    """(device, reason): WAVLIGHT_CL_DEVICE's choice, else the first PoCL CPU device that can
    build a program, else the first other CPU device, else any device that builds."""
    devices = list_devices()
    if not devices:
        raise WavlightError(f"no OpenCL platform found: {no_device_advice()}")
    want = os.environ.get(DEVICE_ENV, "").strip()
    if want:
        m = re.fullmatch(r"(\d+):(\d+)", want)
        for pi, di, p, d in devices:
            hit = (m and (pi, di) == (int(m[1]), int(m[2]))) or (
                not m and want.lower() in f"{p.name} {p.version} {d.name}".lower())
            if hit:
                problem = build_problem(d)
                if problem:
                    raise WavlightError(f"{DEVICE_ENV}={want!r}: device {d.name!r} cannot build programs "
                                        f"({problem})")
                return d, f"{DEVICE_ENV}={want!r} chose it"
        raise WavlightError(f"{DEVICE_ENV}={want!r} matches no OpenCL device (see `wavlight info`)")
    cl = opencl()

    def rank(t):   # PoCL CPU devices first, then other CPUs, then anything else
        _, _, _, d = t
        return (0 if _is_pocl(d) else 1, 0 if d.type & cl.device_type.CPU else 1)

    failed = []
    for _, _, _, d in sorted(devices, key=rank):
        problem = build_problem(d)
        if problem is None:
            if not failed:
                return d, ("the first PoCL CPU device that builds programs" if _is_pocl(d)
                           else "the first device that builds programs")
            why = "; ".join(f"{label} cannot compile for this CPU ({p})" for label, p in failed)
            return d, f"{why}; using {_label(d)}, the next device that builds programs"
        failed.append((_label(d), problem))
    why = "; ".join(f"{label}: {p}" for label, p in failed)
    raise WavlightError(f"no OpenCL device can build programs ({why}): {no_device_advice()}")


_lock = threading.RLock()
_runtime: Runtime | None = None


def runtime() -> Runtime:
    """The process-wide OpenCL runtime (created on first use)."""
    global _runtime
    with _lock:
        if _runtime is None:
            cl = opencl()
            dev, reason = _pick_device()
            ctx = cl.Context([dev])
            _runtime = Runtime(ctx, cl.CommandQueue(ctx), dev, reason)
        return _runtime


_local = threading.local()


def thread_queue():
    """An in-order command queue of the calling thread (queues are cheap; kernels are not shared)."""
    q = getattr(_local, "queue", None)
    if q is None:
        q = _local.queue = opencl().CommandQueue(runtime().context)
    return q


def kernel_source(name: str) -> str:
    """The text of ``kernels/<name>`` with local ``#include "..."`` lines spliced in."""
    pkg = resources.files("wavlight.kernels")

    def load(fname, seen):
        if fname in seen:
            return ""
        seen.add(fname)
        text = (pkg / fname).read_text()
        return re.sub(r'^\s*#include\s+"([^"]+)"\s*$',
                      lambda m: load(m.group(1), seen), text, flags=re.M)

    return load(name, set())


_log = logging.getLogger("wavlight.cl")
_noted_compiling = False


def _note_compiling(device) -> None:
    """One log line (the CLI shows it on stderr) before the first build this machine has not
    done before: compiling the kernels takes seconds, once."""
    global _noted_compiling
    if not _noted_compiling:
        _noted_compiling = True
        _log.info("compiling OpenCL kernels for %s (once; later runs reuse them)", device.name.strip())


def _cached_build_path(device, source: str, opts: str):
    """Where the build of (source, opts) for `device` is remembered: ``<key>.bin``, the program's
    binary, for drivers that keep no cache of their own; ``<key>.built``, a marker, for PoCL,
    which caches compiled kernels itself (~/.cache/pocl). None when no cache folder can be made."""
    ident = "\0".join([device.platform.name, device.platform.version, device.name, device.version,
                        device.driver_version, opts, source])
    key = hashlib.sha256(ident.encode()).hexdigest()[:32]
    try:
        folder = cache_dir("kernels")
    except OSError:
        return None
    return folder / (key + (".built" if _is_pocl(device) else ".bin"))


def _remember(path, content: bytes) -> None:
    import tempfile

    try:
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=".wavlight-", suffix=".tmp", delete=False) as f:
            f.write(content)
        os.replace(f.name, path)
    except OSError:   # a cache that cannot be written only costs the next process a build
        try:
            os.unlink(f.name)
        except (OSError, NameError):
            pass


@functools.lru_cache(maxsize=None)
def _build(ctx, name: str, defines: tuple):
    """The program ``name`` built with ``defines``. It is built with exactly these options:
    pyopencl's own build adds ``-I <its install path>``, which enters the driver's kernel
    cache key (PoCL's), so that every new virtual environment compiled every kernel again.

    Drivers without a kernel cache of their own (Intel's CPU runtime: 17-20 s of builds per
    process) get wavlight's: the program's binary, loaded in about 10 ms the next time."""
    cl = opencl()
    opts = " ".join([f"-D{k}={v}" for k, v in defines] + [f"-DLANES={LANES}"])   # kernels/simd.h
    source = kernel_source(name)
    device = ctx.devices[0]
    remembered = _cached_build_path(device, source, opts)
    damaged = False
    if remembered is not None and remembered.is_file():
        if remembered.suffix == ".bin":
            try:
                prg = cl._cl._Program(ctx, [device], [remembered.read_bytes()])
                prg.build(opts.encode(), None)
                return cl.Program(prg)
            except Exception:   # stale or damaged: build from the source and replace it
                damaged = True
                _note_compiling(device)
    else:
        _note_compiling(device)
    prg = cl._cl._Program(ctx, source)
    try:
        prg.build(opts.encode(), None)
    except cl.Error as e:
        log = "\n".join(prg.get_build_info(d, cl.program_build_info.LOG) for d in ctx.devices)
        raise cl.RuntimeError(f"building kernels/{name} with {opts}: {e}\n{log}") from None
    if remembered is not None and (damaged or not remembered.is_file()):
        _remember(remembered, b"" if remembered.suffix == ".built"
                  else prg.get_info(cl.program_info.BINARIES)[0])
    return cl.Program(prg)


def inline_builtins(device) -> bool:
    """Whether programs for `device` replace OpenCL builtins by kernels/simd.h's inline
    equivalents (-DINLINE_BUILTINS=1): on PoCL CPU devices, whose kernel library the
    PyPI build calls out of line (2.3x slower product walks, see there).
    ``WAVLIGHT_INLINE_BUILTINS=0`` or ``1`` overrides the choice."""
    want = os.environ.get(INLINE_ENV, "").strip()
    if want in ("0", "1"):
        return want == "1"
    if want:
        raise WavlightError(f"{INLINE_ENV}={want!r}: must be 0 or 1 (or unset: chosen per device)")
    cl = opencl()
    return _is_pocl(device) and bool(device.type & cl.device_type.CPU)


@functools.lru_cache(maxsize=None)
def builtins_inlined() -> bool:
    """Whether the runtime's programs use kernels/simd.h's inline builtins: requested by
    :func:`inline_builtins` and accepted by the compiler (clang 14 or newer). Builds and
    runs one tiny kernel, once per process."""
    out = empty(4)
    q = thread_queue()
    kernel(program("simd.cl"), "builtins_inlined")(q, (1,), None, out)
    return bool(read(out, (1,), np.int32, q)[0])


def program(name: str, **defines):
    """The built program ``kernels/<name>``, memoised per (context, name, defines).
    INLINE_BUILTINS defaults to :func:`inline_builtins` of the runtime's device."""
    rt = runtime()
    defines.setdefault("INLINE_BUILTINS", int(inline_builtins(rt.device)))
    with _lock:
        return _build(rt.context, name, tuple(sorted(defines.items())))


def kernel(prog, name: str):
    """The calling thread's kernel object for (prog, name).

    Kernel objects hold their arguments, so they are never shared across threads; within
    a thread one is reused (every call sets all arguments), because creating one costs
    about 0.6 ms in pyopencl (it generates and caches an invoker): 3% of a render, profiled.
    """
    cache = getattr(_local, "kernels", None)
    if cache is None:
        cache = _local.kernels = {}
    knl = cache.get((prog, name))
    if knl is None:
        knl = cache[(prog, name)] = opencl().Kernel(prog, name)
    return knl


def to_device(a: np.ndarray, writable: bool = False):
    """A device buffer holding a copy of ``a``."""
    cl = opencl()
    flags = (cl.mem_flags.READ_WRITE if writable else cl.mem_flags.READ_ONLY) | cl.mem_flags.COPY_HOST_PTR
    return cl.Buffer(runtime().context, flags, hostbuf=np.ascontiguousarray(a))


def empty(nbytes: int):
    cl = opencl()
    return cl.Buffer(runtime().context, cl.mem_flags.READ_WRITE, size=max(int(nbytes), 4))


def read(buf, shape, dtype, queue=None) -> np.ndarray:
    cl = opencl()
    out = np.empty(shape, dtype)
    cl.enqueue_copy(queue or runtime().queue, out, buf)
    return out


def scratch(name: str, nbytes: int):
    """The calling thread's reusable device buffer `name`, at least nbytes long.

    Per-batch buffers of the renderer (inputs and outputs of the shade kernels) are
    reused across batches instead of allocated each time: fresh buffers cost PoCL an
    allocation and first-touch page faults. A thread's buffers are only used by that
    thread's in-order queue; they grow to its largest batch (the renderer's are bounded by
    integrator.TILE_SAMPLES) and are freed with the thread.
    """
    pool = getattr(_local, "scratch", None)
    if pool is None:
        pool = _local.scratch = {}
    buf = pool.get(name)
    if buf is None or buf.size < nbytes:
        buf = pool[name] = empty(max(int(nbytes), 4) + (int(nbytes) >> 3))   # 12% headroom
    return buf


def upload(name: str, a: np.ndarray, queue, blocking: bool = True):
    """`a` copied into the calling thread's scratch buffer `name`, which is returned; with
    ``blocking=False`` the copy is only enqueued (pyopencl keeps `a` alive until it is done), so
    that the uploads before a kernel cost the host no wait each: the queue is in order."""
    a = np.ascontiguousarray(a)
    buf = scratch(name, a.nbytes)
    opencl().enqueue_copy(queue, buf, a, is_blocking=bool(blocking))
    return buf
