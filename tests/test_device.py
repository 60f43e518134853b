"""OpenCL device choice, kernel sources and the program cache (wavlight/cl.py)."""
import os
import subprocess
import sys

import numpy as np

from wavlight import cl

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
