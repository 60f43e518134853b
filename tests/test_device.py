"""OpenCL device choice, kernel sources and the program cache (wavlight/cl.py)."""
import os
import subprocess
import sys

import numpy as np
import pytest

from wavlight import cl
from wavlight.errors import WavlightError

WAVLIGHT = os.path.join(os.path.dirname(sys.executable), "wavlight")


def test_programs_are_built_once_per_process():
    before = cl._build.cache_info()
    a = cl.program("warp.cl", N_LEVELS=4, BATCHED=0)
    b = cl.program("warp.cl", BATCHED=0, N_LEVELS=4)
    after = cl._build.cache_info()
    assert a is b
    assert after.hits >= before.hits + 1
    assert cl.program("shade.cl", STRATEGY=1) is not cl.program("shade.cl", STRATEGY=2)


def test_local_includes_are_spliced_once():
    src = cl.kernel_source("shade.cl")
    assert '#include "' not in src
    # warp.h is included by shade.cl directly and through product.h: its body appears once
    assert src.count("INLINE realv choose_child(") == 1


def test_device_env_var_selects_and_rejects(tmp_path):
    env = dict(os.environ, WAVLIGHT_CL_DEVICE="no-such-device-xyz")
    r = subprocess.run([WAVLIGHT, "info"], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert "no-such-device-xyz" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    name = cl.runtime().device.name
    env = dict(os.environ, WAVLIGHT_CL_DEVICE=name[:12])
    r = subprocess.run([WAVLIGHT, "info"], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    assert name in r.stdout


def test_thread_queues_are_per_thread():
    import threading

    queues = []
    t = threading.Thread(target=lambda: queues.append(cl.thread_queue()))
    t.start()
    t.join()
    assert queues[0] is not cl.thread_queue()
    assert cl.thread_queue() is cl.thread_queue()
    assert np.isfinite(cl.read(cl.to_device(np.ones(4, np.float32)), (4,), np.float32)).all()


def test_inline_builtins_equal_the_librarys():
    """kernels/simd.h's inline builtins (INLINE_BUILTINS=1, the default on PoCL CPU devices)
    give the device library's results bit for bit, rsqrt within 2 ulp (the library's own
    bound), in the argument forms the kernels use, on ordinary values, NaN, +-inf, +-0,
    denormals and halves (rint: ties to even); and the unaligned GATHER2 / GATHER4 loads
    give the floats they point at."""
    rt = cl.runtime()
    if not cl.inline_builtins(rt.device):
        pytest.skip("inline builtins are used on PoCL CPU devices only")
    assert cl.builtins_inlined()   # this compiler takes them: the comparison below is real
    q = cl.thread_queue()
    rng = np.random.default_rng(60)
    n = 4096 + 5   # a partial last work-item
    special = np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, 1e-40, -1e-40, 0.5, 1.5, 2.5, -0.5, -2.5,
                        1.0, -1.0, 3e38, 1e-30], np.float32)
    a, b, c = (np.concatenate([rng.choice(special, 1024), rng.normal(0, 4, n - 1024)]).astype(np.float32)
               for _ in range(3))
    a[:len(special)] = special
    m = rng.choice(np.array([-1, 0, 5, -7, 2 ** 31 - 1, -2 ** 31], np.int32), n)
    m[:8 * 64] = np.repeat(rng.choice([-1, 0], (64, 1)), 8, 1).ravel()   # whole work-items true / false for any / all
    x, y = (rng.integers(0, 2 ** 32, n, dtype=np.uint64).astype(np.uint32) for _ in range(2))
    rows = 29
    outs = {}
    for inline in (0, 1):
        knl = cl.kernel(cl.program("simd.cl", INLINE_BUILTINS=inline), "builtin_ops")
        out = cl.empty(4 * rows * n)
        knl(q, (cl.items(n, cl.LANES),), (cl.WORK_GROUP,), np.uint32(n), *(cl.to_device(v) for v in (a, b, c, m, x, y)),
            out)
        outs[inline] = cl.read(out, (rows, n), np.float32, q)
    lib, mine = outs[0].view(np.uint32), outs[1].view(np.uint32)
    rsqrt = 10
    for k in range(rows):
        if k == rsqrt:
            continue
        bad = np.flatnonzero(lib[k] != mine[k])
        assert bad.size == 0, f"output {k}: {bad.size} lanes differ, e.g. a={a[bad[0]]} b={b[bad[0]]}"
    r_lib, r_mine = outs[0][rsqrt].astype(np.float64), outs[1][rsqrt].astype(np.float64)
    same = (r_lib == r_mine) | (np.isnan(r_lib) & np.isnan(r_mine))
    ulp = np.spacing(np.abs(outs[0][rsqrt])).astype(np.float64)
    with np.errstate(invalid="ignore"):   # inf - inf where both are inf (then `same`)
        assert np.all(same | (np.abs(r_lib - r_mine) <= 2 * ulp))
    # the gathers against numpy: a[j .. j + 3] and a[j + 2 .. j + 3], j = min(i, n - 5) + 1
    j = np.minimum(np.arange(n), n - 5) + 1
    want = np.stack([a[j], a[j + 1], a[j + 2], a[j + 3], a[j + 2], a[j + 3]]).view(np.uint32)
    assert np.array_equal(mine[23:29], want) and np.array_equal(lib[23:29], want)


def test_inline_builtins_env_var_overrides(monkeypatch):
    dev = cl.runtime().device
    monkeypatch.setenv(cl.INLINE_ENV, "0")
    assert cl.inline_builtins(dev) is False
    monkeypatch.setenv(cl.INLINE_ENV, "1")
    assert cl.inline_builtins(dev) is True
    for bad in ("yes", "2"):   # not silently the automatic choice: a one-line error
        monkeypatch.setenv(cl.INLINE_ENV, bad)
        with pytest.raises(WavlightError, match=f"{cl.INLINE_ENV}='{bad}': must be 0 or 1"):
            cl.inline_builtins(dev)
