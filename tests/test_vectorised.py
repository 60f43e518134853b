"""The product walk stays vectorisable by PoCL (kernels/product.h product_walk, one walk per
work-item, scalar code). (kernels/warp.cl and kernels/shade.cl are written in vector types,
kernels/simd.h, and need no vectoriser.)

A structural check, not a timing: each program is built and launched once in a subprocess with
PoCL's vectoriser remarks on, and no work-item loop may report "loop not vectorized" (a legality
failure: LLVM's SLP vectoriser paired two identical scalar chains into a short vector, or a library
call or vector type is left in the loop, after which the kernel runs 1.5-3x slower with identical
results; only this test notices). Whether the vectoriser then finds 8 lanes profitable is its cost
model's call and depends on the CPU: with AVX-512 it vectorises them ("vectorized loop"); on
AVX2-only CPUs it judges the gathers too costly ("vectorization is not beneficial"), and the SLP
vectoriser's own cost model there pairs other chains than with AVX-512, which then costs nothing.
So the check runs where vectorisation pays, on CPUs with AVX-512 (the kernels were written
against PoCL 3.1 / LLVM 15 on an AMD Zen 5), and is skipped elsewhere.
Skipped where the device gives no vectoriser remarks (another OpenCL driver, or a PoCL without
them), and on PoCL builds with LLVM older than 15 (checked on PoCL 3.1, LLVM 15).
"""
import os
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import pytest

SCRIPT = r"""
import sys
import numpy as np
from wavlight import cl

q = cl.thread_queue()
n = 256
f = cl.to_device(np.random.default_rng(0).random(1 << 22).astype(np.float32))
out_uv, out_pdf = cl.empty(8 * n), cl.empty(4 * n)
for spec in sys.argv[1:]:
    name, *kv = spec.split(",")
    defs = {k: int(v) for k, v in (x.split("=") for x in kv)}
    if name == "probe":
        prog = cl._cl().Program(cl.runtime().context, "__kernel void probe(__global float *a)"
                                " { a[get_global_id(0)] *= 2.0f; }").build()
        cl.kernel(prog, "probe")(q, (n,), (64,), out_uv)
    else:
        mat = cl.to_device(np.zeros(n, np.int32))
        code = cl.to_device(np.array([defs["PRODUCT_LEVELS"] + 256 * defs.pop("SHAPE")], np.int32))
        knl = cl.kernel(cl.program("product.cl", **defs), "product_sample_points")
        knl(q, (n,), (64,), f, f, np.uint32(n), f, f, mat, f, code, f, np.uint32(2), f, out_uv, out_pdf)
    q.finish()
"""


def remarks(spec):
    """PoCL's vectoriser remarks (it prints them on stdout) for building and launching one program."""
    env = dict(os.environ, POCL_VECTORIZER_REMARKS="1", POCL_KERNEL_CACHE="0")
    r = subprocess.run([sys.executable, "-c", SCRIPT, spec], env=env, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout + r.stderr


WALKS = [
    f"product,N_LEVELS=10,PRODUCT_LEVELS={p},LOBE_SHAPES={mask},SHAPE={shape}"
    for p, mask, shape in ((3, 1, 0), (7, 2, 1), (7, 4, 2), (5, 8, 3), (7, 15, 1), (3, 3, 0), (5, 12, 3))]


def test_walk_kernels_are_vectorisable():
    desc = __import__("wavlight").cl.runtime().description
    if "pocl" not in desc.lower():
        pytest.skip("not a PoCL device")
    llvm = re.search(r"LLVM (\d+)", desc)
    if not llvm or int(llvm.group(1)) < 15:
        # verified with PoCL 3.1 on LLVM 15; LLVM 14's vectorisers were not available here to check
        pytest.skip(f"vectorisation checked on PoCL with LLVM >= 15 only ({desc})")
    flags = open("/proc/cpuinfo").read() if os.path.exists("/proc/cpuinfo") else ""
    if "avx512f" not in flags:
        pytest.skip("no AVX-512: PoCL's cost model does not vectorise gathers here (see the module docstring)")
    if "vectorized loop" not in remarks("probe"):
        pytest.skip("this PoCL gives no vectoriser remarks")
    with ThreadPoolExecutor(2) as pool:
        chunks = dict(zip(WALKS, pool.map(remarks, WALKS)))
    decided = ("vectorized loop", "vectorization is not beneficial")   # legal; the cost model decided
    bad = [spec for spec in WALKS
           if "loop not vectorized" in chunks[spec] or not any(d in chunks[spec] for d in decided)]
    assert not bad, f"PoCL can no longer vectorise: {bad}; remarks: {chunks[bad[0]][-1500:]}"
