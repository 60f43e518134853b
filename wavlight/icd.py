"""OpenCL drivers installed by pip, made known to the OpenCL ICD loader.

The ICD loader (ocl-icd, which pyopencl's wheels bundle) loads the drivers that the ``.icd``
files of one folder name: ``OCL_ICD_VENDORS`` when it is set (a folder, or one ``.icd``
file), else ``OPENCL_VENDOR_PATH``, else ``/etc/OpenCL/vendors``; pyopencl's wheel adds the
PoCL it carries. A driver that pip installs into the environment has no ``.icd`` file that
names it: the ``intel-opencl-rt`` wheel's own names the path of a conda build. That driver,
Intel's OpenCL CPU runtime (``libintelocl.so``, with its maths libraries from
``intel-cmplr-lib-rt``), is wavlight's fallback on Linux x86-64 where the PyPI PoCL cannot
compile for the CPU (docs/decisions/opencl-fallback.md).

:func:`register` writes a folder that holds a copy of every ``.icd`` file of the folder the
loader would read, plus one naming the environment's driver, and points ``OCL_ICD_VENDORS``
at it. It must run before the loader's first use in the process (:mod:`wavlight.cl` calls it
before importing pyopencl); the system's drivers stay visible, and a folder the user chose
with ``OCL_ICD_VENDORS`` is the one extended.
"""
from __future__ import annotations

import hashlib
import os
import stat
import sys
import tempfile
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

from .cache import cache_dir

SYSTEM_VENDORS = Path("/etc/OpenCL/vendors")
#: a file in the folders that register() writes: such a folder already holds the pip drivers
MARKER = "wavlight-pip-drivers"


@dataclass(frozen=True)
class PipDriver:
    """An OpenCL driver installed by pip: its distribution and its library."""

    distribution: str
    library: Path
    settings: tuple = ()

    @property
    def icd_name(self) -> str:
        return f"wavlight-{self.distribution}.icd"


#: (distribution, the library that is the driver, a library the driver loads beside it,
#: environment defaults for the driver). Intel's implicit vectorizer packs work-items into SIMD
#: lanes; wavlight's kernels already take eight points per work-item in vector types
#: (kernels/simd.h), and with it on, a cold build of the default scene's kernels took 47 s
#: instead of 6 s at the same render time (docs/decisions/opencl-fallback.md).
KNOWN = (("intel-opencl-rt", "libintelocl.so", "libimf.so", {"CL_CONFIG_USE_VECTORIZER": "False"}),)


def pip_drivers() -> list[PipDriver]:
    """The OpenCL drivers installed by pip in this environment whose libraries are all present
    (Linux only: elsewhere the platform's own OpenCL is used)."""
    if not sys.platform.startswith("linux"):
        return []
    found = []
    for dist_name, library, companion, settings in KNOWN:
        try:
            dist = metadata.distribution(dist_name)
        except metadata.PackageNotFoundError:
            continue
        for f in dist.files or ():
            if f.name == library:
                path = Path(dist.locate_file(f)).resolve()
                if path.is_file() and (path.parent / companion).is_file():
                    found.append(PipDriver(dist_name, path, tuple(settings.items())))
                break
    return found


def loader_vendors() -> Path | None:
    """The folder (or single .icd file) the ICD loader reads, by its own rules."""
    for var in ("OCL_ICD_VENDORS", "OPENCL_VENDOR_PATH"):
        value = os.environ.get(var, "").strip()
        if value:
            return Path(value)
    return SYSTEM_VENDORS


def _icd_files(source: Path | None) -> list[tuple[str, bytes]]:
    if source is None:
        return []
    try:
        if source.is_file():
            return [(source.name, source.read_bytes())]
        if source.is_dir():
            return [(p.name, p.read_bytes()) for p in sorted(source.glob("*.icd")) if p.is_file()]
    except OSError:
        pass
    return []


def vendor_folder(drivers: list[PipDriver], source: Path | None) -> Path:
    """A folder of .icd files for the loader: those of `source` (a folder, or one .icd file) and
    one naming each of `drivers`. Folders are kept in the cache by content and reused."""
    files = [(name, content) for name, content in _icd_files(source) if not name.startswith("wavlight-")]
    files += [(d.icd_name, f"{d.library}\n".encode()) for d in drivers]
    digest = hashlib.sha256(repr(files).encode()).hexdigest()[:16]
    try:
        root = cache_dir("opencl-vendors")
    except OSError:
        root = _private_folder(Path(tempfile.gettempdir()) / f"wavlight-opencl-vendors-{os.getuid()}")
    target = root / digest
    if (target / MARKER).is_file():
        return target
    staging = Path(tempfile.mkdtemp(prefix=f".{digest}.", dir=root))
    for name, content in files:
        (staging / name).write_bytes(content)
    (staging / MARKER).write_text("written by wavlight.icd\n")
    try:
        os.rename(staging, target)
    except OSError:   # another process wrote it first: use theirs
        for p in staging.iterdir():
            p.unlink()
        staging.rmdir()
    return target


def _private_folder(folder: Path) -> Path:
    """``folder`` (made if missing) where only this user can write: the loader loads the library
    that each .icd file there names, so a folder of a shared temporary directory that another user
    made first, or may write into, is refused (OSError)."""
    try:
        folder.mkdir(mode=0o700)
    except FileExistsError:
        pass
    st = folder.lstat()
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o022:
        raise OSError(f"{folder}: not a folder of this user's alone")
    return folder


def pocl_cache() -> None:
    """PoCL keeps its compiled kernels in ``$POCL_CACHE_DIR``, else ``$XDG_CACHE_HOME/pocl`` (else
    ``~/.cache/pocl``), and gives no device at all where that cannot be written: then (and only
    when the user has not set it) ``POCL_CACHE_DIR`` names a private temporary folder, so that
    PoCL works, compiling in each process."""
    if os.environ.get("POCL_CACHE_DIR", "").strip():
        return
    root = os.environ.get("XDG_CACHE_HOME", "").strip() or os.path.join(os.path.expanduser("~"), ".cache")
    folder = os.path.join(root, "pocl")
    try:
        os.makedirs(folder, exist_ok=True)
        if os.access(folder, os.W_OK | os.X_OK):
            return
    except OSError:
        pass
    os.environ["POCL_CACHE_DIR"] = tempfile.mkdtemp(prefix="wavlight-pocl-cache-")


_registered: list[PipDriver] | None = None


def register() -> list[PipDriver]:
    """Make the pip-installed drivers visible to the ICD loader (once per process, before the
    loader's first use); returns them. Nothing changes when none is installed or when the
    loader's folder is already one of :func:`vendor_folder`'s."""
    global _registered
    if _registered is not None:
        return _registered
    pocl_cache()
    drivers = pip_drivers()
    source = loader_vendors()
    if drivers and not (source is not None and (source / MARKER).is_file()):
        try:
            os.environ["OCL_ICD_VENDORS"] = str(vendor_folder(drivers, source))
        except OSError:   # no folder can be written: the loader keeps its own list
            drivers = []
    for d in drivers:
        for key, value in d.settings:   # the user's own setting wins
            os.environ.setdefault(key, value)
    _registered = drivers
    return drivers
