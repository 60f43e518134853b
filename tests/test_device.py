"""OpenCL device choice, kernel sources and the program cache (wavlight/cl.py)."""
import os
import stat
import subprocess
import sys
import tempfile

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


# ============================================================================= drivers installed by pip
from pathlib import Path  # noqa: E402

from wavlight import icd  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def test_vendor_folder_keeps_the_loaders_drivers_and_names_the_pip_ones(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    system = tmp_path / "vendors"
    system.mkdir()
    (system / "a.icd").write_text("/opt/a/libA.so\n")
    (system / "notes.txt").write_text("not a driver")
    lib = tmp_path / "lib" / "libintelocl.so"
    driver = icd.PipDriver("intel-opencl-rt", lib)
    folder = icd.vendor_folder([driver], system)
    assert sorted(p.name for p in folder.glob("*.icd")) == ["a.icd", driver.icd_name]
    assert (folder / "a.icd").read_text() == "/opt/a/libA.so\n"
    assert (folder / driver.icd_name).read_text().strip() == str(lib)
    assert (folder / icd.MARKER).is_file()
    # the same content gives the same folder, also when the loader already reads that folder
    assert icd.vendor_folder([driver], system) == folder
    assert icd.vendor_folder([driver], folder) == folder
    # one .icd file as the loader's source; no source at all
    one = icd.vendor_folder([driver], system / "a.icd")
    assert sorted(p.name for p in one.glob("*.icd")) == ["a.icd", driver.icd_name]
    alone = icd.vendor_folder([driver], tmp_path / "missing")
    assert [p.name for p in alone.glob("*.icd")] == [driver.icd_name]


def test_vendor_folder_in_the_temporary_folder_is_this_users_alone(tmp_path, monkeypatch):
    """Where the cache cannot be written the drivers' folder is made in the temporary folder: the
    loader loads the library each .icd file there names, so a folder there that others may write
    into, or that another user made, is refused, and register() leaves the loader its own list."""
    def no_cache(kind):
        raise OSError("read-only")

    monkeypatch.setattr(icd, "cache_dir", no_cache)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    shared = tmp_path / f"wavlight-opencl-vendors-{os.getuid()}"
    driver = icd.PipDriver("intel-opencl-rt", tmp_path / "lib" / "libintelocl.so")
    folder = icd.vendor_folder([driver], None)
    assert folder.parent == shared and stat.S_IMODE(shared.stat().st_mode) == 0o700
    shared.chmod(0o777)
    with pytest.raises(OSError, match="not a folder of this user's alone"):
        icd.vendor_folder([driver], None)
    if os.getuid() == 0:   # a folder that another user made first
        shared.chmod(0o755)
        os.chown(shared, 65534, 65534)
        with pytest.raises(OSError, match="not a folder of this user's alone"):
            icd.vendor_folder([driver], None)


def test_a_damaged_cached_kernel_binary_is_built_again_and_replaced(tmp_path, monkeypatch):
    """A cached program binary that the driver refuses (truncated, garbage): the program is built
    from its source and the binary replaced, so that the next process loads it again."""
    cached = tmp_path / "kernels" / "damaged.bin"
    cached.parent.mkdir()
    cached.write_bytes(b"not a program binary")
    monkeypatch.setattr(cl, "_cached_build_path", lambda device, source, opts: cached)
    prog = cl.program("warp.cl", N_LEVELS=3, BATCHED=0, WAVLIGHT_DAMAGED_CACHE_TEST=1)
    assert cl.kernel(prog, "warp_sample") is not None
    assert cached.stat().st_size > 0 and cached.read_bytes() != b"not a program binary"


def test_a_user_cache_that_cannot_be_written_is_no_traceback(tmp_path):
    """XDG_CACHE_HOME a file: wavlight's kernel cache, the drivers' folder and pyopencl's invoker
    cache (pytools') cannot be made; `wavlight info` still answers (or says in one line that no
    device builds programs)."""
    (tmp_path / "file").write_text("x")
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "file"))
    env.pop("PYOPENCL_NO_CACHE", None)
    r = subprocess.run([WAVLIGHT, "info"], capture_output=True, text=True, env=env, timeout=600)
    assert "Traceback" not in r.stderr, r.stderr[-2000:]
    assert r.returncode == 0 or (r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1), r.stderr
    if r.returncode == 0:
        assert "device in use: " in r.stdout and "OpenCL builtins: " in r.stdout


def test_loader_vendors_follows_the_loaders_own_rules(monkeypatch):
    monkeypatch.delenv("OCL_ICD_VENDORS", raising=False)
    monkeypatch.delenv("OPENCL_VENDOR_PATH", raising=False)
    assert icd.loader_vendors() == icd.SYSTEM_VENDORS
    monkeypatch.setenv("OPENCL_VENDOR_PATH", "/x/vendor-path")
    assert icd.loader_vendors() == Path("/x/vendor-path")
    monkeypatch.setenv("OCL_ICD_VENDORS", "/y/vendors")
    assert icd.loader_vendors() == Path("/y/vendors")


def test_pip_drivers_are_complete_installations():
    for d in icd.pip_drivers():
        assert d.library.is_file()
        assert d.distribution in {known[0] for known in icd.KNOWN}


def _without_system_drivers(tmp_path, **extra):
    """The environment of a machine with no system OpenCL driver: the ICD loader reads an empty
    folder instead of /etc/OpenCL/vendors, so only what pip installed is there."""
    empty = tmp_path / "no-vendors"
    empty.mkdir(exist_ok=True)
    env = {k: v for k, v in os.environ.items() if k not in ("OCL_ICD_VENDORS", "OPENCL_VENDOR_PATH", cl.DEVICE_ENV)}
    env.update(OCL_ICD_VENDORS=str(empty), **extra)
    return env


def _tiny_render(tmp_path, env, name):
    out = tmp_path / name
    r = subprocess.run([WAVLIGHT, "render", str(REPO / "scenes" / "default.toml"), "--spp", "1", "--width", "16",
                        "--height", "12", "-o", str(out)], capture_output=True, text=True, env=env, timeout=600)
    return r, out


def test_a_machine_without_system_drivers_renders(tmp_path):
    """Only what pip installed: `wavlight info` names the device in use and why, and a tiny
    render of the built-in scene is written."""
    env = _without_system_drivers(tmp_path)
    r = subprocess.run([WAVLIGHT, "info"], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    used = [ln for ln in r.stdout.splitlines() if ln.startswith("device in use: ")]
    why = [ln for ln in r.stdout.splitlines() if ln.startswith("why: ")]
    assert len(used) == 1 and len(why) == 1 and len(why[0]) > len("why: ")
    r, out = _tiny_render(tmp_path, env, "a.exr")
    assert r.returncode == 0, r.stderr
    from wavlight.envmap import read_image
    image = read_image(str(out))
    assert image.shape == (12, 16, 3) and np.isfinite(image).all() and image.max() > 0


@pytest.mark.slow
def test_a_pocl_that_cannot_compile_gives_way(tmp_path):
    """PoCL whose builds fail (here: refused by an option it does not take, as the PyPI PoCL's
    LLVM 14 refuses a CPU newer than it): the next device that builds is used, and `wavlight
    info` says why; with no such device, one line says what to install."""
    env = _without_system_drivers(tmp_path, POCL_EXTRA_BUILD_FLAGS="-march=znver5")
    r = subprocess.run([WAVLIGHT, "info"], capture_output=True, text=True, env=env, timeout=300)
    assert "Traceback" not in r.stderr
    if icd.pip_drivers():
        assert r.returncode == 0, r.stderr
        why = next(ln for ln in r.stdout.splitlines() if ln.startswith("why: "))
        assert "PoCL" in why and "cannot compile for this CPU" in why and "using " in why
        used = next(ln for ln in r.stdout.splitlines() if ln.startswith("device in use: "))
        assert "Portable Computing Language" not in used
        r, out = _tiny_render(tmp_path, env, "b.exr")
        assert r.returncode == 0, r.stderr
        assert out.is_file()
    else:
        assert r.returncode == 2
        error = r.stderr.strip().splitlines()
        assert len(error) == 1 and "no OpenCL device can build programs" in error[0] and "install" in error[0]


@pytest.mark.slow
def test_the_first_build_of_a_program_says_so_once(tmp_path):
    """A build not done before on this machine logs one line before it starts ("compiling
    OpenCL kernels"), and a second process with the same cache says nothing."""
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "cache"))
    code = "from wavlight import cl; cl.program('warp.cl', N_LEVELS=3, BATCHED=0)"
    cli = [sys.executable, "-c", "import logging, sys; logging.basicConfig(stream=sys.stderr, level=logging.INFO); "
           + code]
    first = subprocess.run(cli, capture_output=True, text=True, env=env, timeout=300)
    assert first.returncode == 0, first.stderr
    assert first.stderr.count("compiling OpenCL kernels") == 1
    again = subprocess.run(cli, capture_output=True, text=True, env=env, timeout=300)
    assert again.returncode == 0, again.stderr
    assert "compiling OpenCL kernels" not in again.stderr
    assert any((tmp_path / "cache" / "wavlight" / "kernels").iterdir())


def test_the_device_variable_matches_the_platform_version(monkeypatch):
    """`WAVLIGHT_CL_DEVICE=PoCL`: "PoCL" is in the platform's version only, as `wavlight info` prints it.
    Where that PoCL cannot build programs (a CPU newer than its LLVM), the choice is refused in one
    line saying so; where there is no PoCL, the name matches no device."""
    pocl = [d for pi, di, p, d in cl.list_devices() if "pocl" in p.version.lower()]
    env = dict(os.environ, WAVLIGHT_CL_DEVICE="pocl")
    r = subprocess.run([WAVLIGHT, "info"], capture_output=True, text=True, env=env, timeout=300)
    if pocl and cl.build_problem(pocl[0]) is None:
        assert r.returncode == 0, r.stderr
        assert "Portable Computing Language" in next(ln for ln in r.stdout.splitlines() if ln.startswith("device in"))
    elif pocl:
        assert r.returncode == 2 and "cannot build programs" in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr
    else:
        assert r.returncode == 2 and "matches no OpenCL device" in r.stderr


def test_a_cache_folder_that_cannot_be_written_keeps_pocl(tmp_path):
    """XDG_CACHE_HOME naming a file (no folder can be made in it, whoever runs): PoCL, which gives
    no device where its cache folder cannot be written, is given a private temporary one; the
    device in use is the one chosen without it."""
    base = subprocess.run([WAVLIGHT, "info"], capture_output=True, text=True, timeout=300)
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    env = {k: v for k, v in os.environ.items() if k != "POCL_CACHE_DIR"}
    env["XDG_CACHE_HOME"] = str(blocked)
    code = ("import os; from wavlight import icd; icd.pocl_cache(); d = os.environ['POCL_CACHE_DIR']; "
            "print(d, os.path.isdir(d) and os.access(d, os.W_OK))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    folder, writable = r.stdout.split()
    assert writable == "True" and not folder.startswith(str(blocked))
    r = subprocess.run([WAVLIGHT, "info"], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    pick = [ln for ln in r.stdout.splitlines() if ln.startswith("device in use")]
    assert pick == [ln for ln in base.stdout.splitlines() if ln.startswith("device in use")]
