"""OpenCL device choice, kernel sources and the per-process program cache.

Device choice
-------------
By default wavlight uses the first PoCL CPU device that can actually build a
program. The probe build matters: the PoCL bundled with the PyPI wheels links
LLVM 14, which does not know CPUs newer than it (AMD Zen 5 reports "unknown
target CPU 'generic'"); a system PoCL (Debian's ``pocl-opencl-icd``) next to it
works, and the probe picks whichever does.

``WAVLIGHT_CL_DEVICE`` overrides the choice: ``"P:D"`` (platform and device
indices as ``wavlight info`` lists them) or any text that occurs in
"platform name + device name" (case-insensitive), e.g. ``"NVIDIA"``.
On PoCL CPU devices the kernels use kernels/simd.h's inline equivalents of the
OpenCL builtins (:func:`inline_builtins`); ``WAVLIGHT_INLINE_BUILTINS=0`` or ``1``
overrides that.

Programs
--------
Kernel sources live in the ``kernels/`` folder, installed as the package
``wavlight.kernels``. Local ``#include "x.h"`` lines are spliced on the host
(PoCL has failed on ``-I`` include paths). Each program is built once per
(context, file, defines) and memoised for the life of the process. Kernels that
walk trees are built per tree depth (``-DN_LEVELS``), so that their level loop
unrolls. The per-sample kernels take eight points per work-item in OpenCL vector
types (kernels/simd.h, :data:`LANES`, :func:`items`).
"""
from __future__ import annotations

import functools
import os
import re
import threading
import warnings
from dataclasses import dataclass
from importlib import resources

import numpy as np

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
    """A context and an in-order queue on one device."""

    context: object
    queue: object
    device: object

    @property
    def description(self) -> str:
        p = self.device.platform
        return f"{p.name} ({p.version.strip()}) / {self.device.name}"


def _cl():
    import pyopencl  # deferred: importing it costs ~0.1 s

    return pyopencl


def list_devices():
    """All (platform index, device index, platform, device) tuples."""
    cl = _cl()
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


def _builds(device) -> bool:
    cl = _cl()
    try:
        ctx = cl.Context([device])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cl.Program(ctx, _PROBE_SRC).build()
        return True
    except Exception:  # any build or driver failure disqualifies the device
        return False


def _pick_device():
    devices = list_devices()
    if not devices:
        raise WavlightError(
            "no OpenCL platform found: install pocl-binary-distribution (pip) or a system "
            "OpenCL driver such as Debian's pocl-opencl-icd")
    want = os.environ.get(DEVICE_ENV, "").strip()
    if want:
        m = re.fullmatch(r"(\d+):(\d+)", want)
        for pi, di, p, d in devices:
            hit = (m and (pi, di) == (int(m[1]), int(m[2]))) or (
                not m and want.lower() in f"{p.name} {d.name}".lower())
            if hit:
                if not _builds(d):
                    raise WavlightError(f"{DEVICE_ENV}={want!r}: device {d.name!r} cannot build programs")
                return d
        raise WavlightError(f"{DEVICE_ENV}={want!r} matches no OpenCL device (see `wavlight info`)")
    cl = _cl()
    # PoCL CPU devices first, then other CPUs, then anything else.
    def rank(t):
        _, _, p, d = t
        return (0 if "portable" in p.name.lower() else 1,
                0 if d.type & cl.device_type.CPU else 1)
    for _, _, _, d in sorted(devices, key=rank):
        if _builds(d):
            return d
    raise WavlightError(
        "no OpenCL device can build programs (PoCL's LLVM may not know this CPU: "
        "install Debian's pocl-opencl-icd, or set WAVLIGHT_CL_DEVICE)")


_lock = threading.Lock()
_runtime: Runtime | None = None


def runtime() -> Runtime:
    """The process-wide OpenCL runtime (created on first use)."""
    global _runtime
    with _lock:
        if _runtime is None:
            cl = _cl()
            dev = _pick_device()
            ctx = cl.Context([dev])
            _runtime = Runtime(ctx, cl.CommandQueue(ctx), dev)
        return _runtime


_local = threading.local()


def thread_queue():
    """An in-order command queue of the calling thread (queues are cheap; kernels are not shared)."""
    q = getattr(_local, "queue", None)
    if q is None:
        q = _local.queue = _cl().CommandQueue(runtime().context)
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


@functools.lru_cache(maxsize=None)
def _build(ctx, name: str, defines: tuple):
    """The program ``name`` built with ``defines``. It is built with exactly these options:
    pyopencl's own build adds ``-I <its install path>``, which enters the driver's kernel
    cache key (PoCL's), so that every new virtual environment compiled every kernel again."""
    cl = _cl()
    opts = " ".join([f"-D{k}={v}" for k, v in defines] + [f"-DLANES={LANES}"])   # kernels/simd.h
    prg = cl._cl._Program(ctx, kernel_source(name))
    try:
        prg.build(opts.encode(), None)
    except cl.Error as e:
        log = "\n".join(prg.get_build_info(d, cl.program_build_info.LOG) for d in ctx.devices)
        raise cl.RuntimeError(f"building kernels/{name} with {opts}: {e}\n{log}") from None
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
    cl = _cl()
    return "portable" in device.platform.name.lower() and bool(device.type & cl.device_type.CPU)


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
        knl = cache[(prog, name)] = _cl().Kernel(prog, name)
    return knl


def to_device(a: np.ndarray, writable: bool = False):
    """A device buffer holding a copy of ``a``."""
    cl = _cl()
    flags = (cl.mem_flags.READ_WRITE if writable else cl.mem_flags.READ_ONLY) | cl.mem_flags.COPY_HOST_PTR
    return cl.Buffer(runtime().context, flags, hostbuf=np.ascontiguousarray(a))


def empty(nbytes: int):
    cl = _cl()
    return cl.Buffer(runtime().context, cl.mem_flags.READ_WRITE, size=max(int(nbytes), 4))


def read(buf, shape, dtype, queue=None) -> np.ndarray:
    cl = _cl()
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


def upload(name: str, a: np.ndarray, queue):
    """`a` copied into the calling thread's scratch buffer `name` (blocking), which is returned."""
    a = np.ascontiguousarray(a)
    buf = scratch(name, a.nbytes)
    _cl().enqueue_copy(queue, buf, a)
    return buf
