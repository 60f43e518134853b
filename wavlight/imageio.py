"""Writing images: linear float (.exr, .hdr, .pfm) or clamped, sRGB-encoded 8-bit (.png), atomically.

Negative pixels (an unbiased estimator's shadowed pixels at low spp can average below 0:
the wavelet strategy's control variate) are kept by .exr and .pfm, written as 0 to .hdr,
whose RGBE encoding has no sign (it turned -0.5 into 1.5), and clamped to 0 in .png.

The file appears complete or not at all: pixels go to a temporary file in the
same folder (``.wavlight-<pid>-<target name>.<random><ext>``), which is renamed over the
target only after a successful write. A temporary that a killed process (SIGKILL, a power
cut) left behind is removed by the next successful write of the same target in that folder
(its pid names no running process). SIGTERM during a write removes the temporary, as
Ctrl-C (SIGINT) does.

Memory: the pixels are checked, converted (sRGB, 8-bit; RGBE's clamp at 0) and written in
strips of rows of about :data:`STRIP_BYTES` (OpenImageIO's scanline interface), so that
writing costs a few MiB beyond the image itself whatever its size (the whole-image
conversion for PNG cost about 50 bytes per pixel: 13 GB at 16384 x 16384).
:func:`render_bytes` states what a render of a size needs, :func:`check_memory` refuses
one that will not fit.
"""
from __future__ import annotations

import hashlib
import os
import re
import signal
import tempfile
import threading

import numpy as np

from .errors import ArgumentError, WavlightError, shown

LINEAR = (".exr", ".hdr", ".pfm")
DISPLAY = (".png",)
FORMATS = LINEAR + DISPLAY

#: The largest image save_image writes: renders are at most 16384 a side (wavlight.scene.MAX_SIDE);
#: a larger array (np.broadcast_to makes one of 10^10 pixels in no memory) would fill the disk.
MAX_WRITE_SIDE = 65536
MAX_WRITE_PIXELS = 1 << 30
#: Pixels converted and written per call (rows of at most this many bytes of float32 RGB).
STRIP_BYTES = 1 << 22
#: Bytes per pixel of `wavlight render`, measured (benchmarks/probe_memory.py: 34.4 at 16384 x
#: 16384 for PNG and EXR alike): render_full's film (the image and its standard error, float32
#: RGB each: 24), the CLI's check for NaN / Inf pixels (np.isfinite, its negation and .any: 7)
#: and the tiles in flight. Writing adds a few MiB whatever the size (strips).
RENDER_BYTES_PER_PIXEL = 36
#: What a process needs besides the film: Python, numpy, OpenCL, the scene (measured: 140 MB
#: for the sky alone, ~300 MB with the default scene's geometry).
RENDER_BASE_BYTES = 400 << 20


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Clamp to [0, 1] and apply the sRGB transfer curve."""
    x = np.clip(np.nan_to_num(linear, nan=0.0, posinf=1.0), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _srgb8(strip: np.ndarray) -> np.ndarray:
    """Linear float32 rows -> sRGB-encoded uint8 (the same values as srgb_encode, in float32
    and in place: 4 bytes per value of temporaries instead of 40)."""
    x = np.clip(strip, 0.0, 1.0)                       # a copy (float32); NaN were refused before
    low = x <= np.float32(0.0031308)
    lin = x * np.float32(12.92)
    np.power(x, np.float32(1 / 2.4), out=x)
    x *= np.float32(1.055)
    x -= np.float32(0.055)
    np.copyto(x, lin, where=low)
    x *= np.float32(255.0)
    x += np.float32(0.5)
    return x.astype(np.uint8)


def render_bytes(width: int, height: int) -> int:
    """Peak memory (bytes) of ``wavlight render`` at width x height: RENDER_BYTES_PER_PIXEL per
    pixel plus RENDER_BASE_BYTES (measured by benchmarks/probe_memory.py: the output format
    no longer matters, strips are written)."""
    return int(width) * int(height) * RENDER_BYTES_PER_PIXEL + RENDER_BASE_BYTES


def available_bytes() -> int | None:
    """Memory the system can give a process now (MemAvailable; None where unknown)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, OSError, ValueError):
        return None


def _gb(n: int) -> str:
    return f"{n / 1e9:.1f} GB" if n >= 1e8 else f"{n / 1e6:.0f} MB"


def check_memory(what: str, width: int, height: int, copies: int = 1) -> int:
    """A one-line WavlightError when ``copies`` renders of width x height (:func:`render_bytes`)
    need more memory than the system has available now; else the bytes they need."""
    need = render_bytes(width, height) * copies
    have = available_bytes()
    if have is not None and need > have:
        raise WavlightError(f"{what}: a {width}x{height} render needs about {_gb(need)} of memory "
                            f"({RENDER_BYTES_PER_PIXEL} bytes per pixel{f' x {copies}' if copies > 1 else ''}); "
                            f"{_gb(have)} is available")
    return need


# ----------------------------------------------------------------------------- inputs and outputs
def same_file(a, b) -> bool:
    """Whether paths a and b name the same file: the same absolute path, the same file after
    symbolic links, or the same inode (hard links)."""
    a, b = os.fspath(a), os.fspath(b)
    if os.path.abspath(a) == os.path.abspath(b) or os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        sa, sb = os.stat(a), os.stat(b)
    except (OSError, ValueError):
        return False
    return (sa.st_dev, sa.st_ino) == (sb.st_dev, sb.st_ino)


def scene_files(scene_path) -> list:
    """The files a scene file reads: itself, its environment map and its meshes (absolute paths,
    relative ones resolved against the scene's folder and ``data:`` names as load_scene does). For a scene that
    load_scene accepted; anything unreadable is skipped (a Scene built in Python: [])."""
    import tomllib

    if not isinstance(scene_path, (str, os.PathLike)):
        return []
    scene_path = os.path.abspath(os.fspath(scene_path))
    files = [scene_path]
    try:
        with open(scene_path, "rb") as fh:
            doc = tomllib.load(fh)
    except (OSError, ValueError, RecursionError):
        return files
    from .data import resolve

    base = os.path.dirname(scene_path)
    env = doc.get("environment")
    named = [env.get("file")] if isinstance(env, dict) else []
    objects = doc.get("objects")
    named += [o.get("mesh") for o in (objects if isinstance(objects, list) else []) if isinstance(o, dict)]
    for name in named:
        if isinstance(name, str):
            try:   # a "data:NAME" asset where it is, or would be, without fetching it
                files.append(resolve(name, base, download=False))
            except WavlightError:
                pass
    return files


def check_not_input(outputs, inputs) -> None:
    """A one-line WavlightError, before anything is rendered, when an output path names one of
    the run's inputs (the scene, its map or a mesh; an experiment's spec or reference): the
    write would replace it."""
    inputs = [i for i in inputs if i is not None]
    for out in outputs:
        if out is None:
            continue
        for inp in inputs:
            if same_file(out, inp):
                raise WavlightError(f"{out}: is an input of this run ({inp}); writing it would replace that "
                                    "file: choose another output")


def save_image(path: str, image: np.ndarray) -> None:
    """Write an (H, W, 3) float image; the format follows the extension (.exr .hdr .pfm .png)."""
    save_images([(path, image)])


def save_images(outputs) -> None:
    """Write several (path, image) pairs all or nothing: every image goes to its temporary
    file first, and the temporaries are renamed over the targets only once all are written
    (an error in any leaves none of them written)."""
    try:
        pairs = list(outputs)
        if not all(isinstance(p, (tuple, list)) and len(p) == 2 for p in pairs):
            raise TypeError
    except TypeError:
        raise ArgumentError(f"save_images: outputs must be (path, image) pairs, got {shown(outputs)}") from None
    outputs = [(_path(path), image) for path, image in pairs]
    for n, (path, _) in enumerate(outputs):
        if any(same_file(path, other) for other, _ in outputs[:n]):
            raise ArgumentError(f"{path}: named twice among the outputs")
    temps = []
    path = outputs[0][0] if outputs else ""
    with _terminate_as_exit():
        try:
            for path, image in outputs:
                temps.append((_write_temporary(path, image), path))
            for tmp, path in temps:
                os.replace(tmp, path)
        except OSError as e:
            _remove(t for t, _ in temps)
            raise WavlightError(f"{path}: cannot write ({e.strerror or e})") from None
        except MemoryError:
            _remove(t for t, _ in temps)
            raise WavlightError(f"{path}: not enough memory to write the image") from None
        except BaseException:
            _remove(t for t, _ in temps)
            raise
    for folder in {os.path.dirname(os.path.abspath(p)) for _, p in temps}:
        remove_stale_temporaries(folder)


def _path(path) -> str:
    """An output path as a str, or a one-line ArgumentError (None, a number, bytes, "", a NUL)."""
    p = os.fspath(path) if isinstance(path, (str, os.PathLike)) else None
    if not isinstance(p, str) or not p or "\0" in p:
        raise ArgumentError(f"save_image: the path must be a file name (str or os.PathLike), got {shown(path)}")
    return p


class _Terminated(SystemExit):
    """SIGTERM during a write: the temporaries are removed on the way out (exit code 143)."""


class _terminate_as_exit:
    """While writing (on the main thread only, where signal handlers run, and only while SIGTERM
    has its default action): SIGTERM raises SystemExit(128 + 15) instead of ending the process
    at once, so that no temporary is left behind; the default is restored afterwards."""

    def __enter__(self):
        self.previous = None
        # only where SIGTERM would end the process anyway (the default action): a handler the
        # program installed, or SIG_IGN, is left alone
        if (threading.current_thread() is threading.main_thread()
                and signal.getsignal(signal.SIGTERM) == signal.SIG_DFL):
            try:
                self.previous = signal.signal(signal.SIGTERM, self._handler)
            except (ValueError, OSError):   # not the main interpreter
                self.previous = None
        return self

    @staticmethod
    def _handler(signum, frame):
        raise _Terminated(128 + signum)

    def __exit__(self, *exc):
        if self.previous is not None:
            signal.signal(signal.SIGTERM, self.previous)
        return False


def _remove(paths):
    for tmp in paths:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass


TEMPORARY_PREFIX = ".wavlight-"
#: .wavlight-<pid>.<host>-<target's name>.<random><ext>: whose it is, for remove_stale_temporaries
_TEMPORARY = re.compile(r"^\.wavlight-(\d+)\.([0-9a-f]{8})-(.*)\.[A-Za-z0-9_]{6,}(\.[A-Za-z0-9]+)?$")


def _host() -> str:
    """8 hex digits naming this machine (a folder may be shared with writers on others)."""
    return hashlib.sha1(os.uname().nodename.encode()).hexdigest()[:8]


def temporary(target: str, suffix: str | None = None) -> tuple[int, str]:
    """(fd, name) of a new temporary file beside ``target`` for an atomic write, named
    ``.wavlight-<pid>.<host>-<target's name>.<random><suffix>`` (suffix: the target's
    extension), so that :func:`remove_stale_temporaries` can tell whose it is."""
    folder = os.path.dirname(os.path.abspath(target))
    base = os.path.basename(target)
    ext = os.path.splitext(base)[1] if suffix is None else suffix
    return tempfile.mkstemp(prefix=f"{TEMPORARY_PREFIX}{os.getpid()}.{_host()}-{base[:100]}.", suffix=ext,
                            dir=folder)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True   # another user's process (or not a pid we can ask about): keep its file
    return True


def remove_stale_temporaries(folder: str) -> list:
    """Remove from ``folder`` the temporaries that killed writers left (SIGKILL, a power cut):
    files named by :func:`temporary` on this machine whose pid is no running process. A live
    writer's file, or another machine's, is never touched. Returns the names removed."""
    removed = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    host = _host()
    for name in names:
        m = _TEMPORARY.match(name)
        if not m or m.group(2) != host:
            continue
        pid = int(m.group(1))
        if pid == os.getpid() or _alive(pid):
            continue
        try:
            os.unlink(os.path.join(folder, name))
            removed.append(name)
        except OSError:
            pass
    return removed


def _check_pixels(path: str, image) -> np.ndarray:
    """image as an (H, W, 3) array of real numbers (not copied), or a one-line error."""
    if isinstance(image, np.ndarray):
        a = image
    else:
        try:
            a = np.asarray(image)
        except (TypeError, ValueError, MemoryError):
            raise ArgumentError(f"{path}: expected an (H, W, 3) image of numbers, got {shown(image)}") from None
    if a.dtype.kind not in "biuf":
        raise ArgumentError(f"{path}: expected an (H, W, 3) image of real numbers, got {shown(image)}")
    if a.ndim != 3 or a.shape[2] != 3:
        raise WavlightError(f"{path}: expected an (H, W, 3) image, got shape {a.shape}")
    if a.shape[0] < 1 or a.shape[1] < 1:
        raise WavlightError(f"{path}: expected an (H, W, 3) image, got an empty one of shape {a.shape}")
    if a.shape[0] > MAX_WRITE_SIDE or a.shape[1] > MAX_WRITE_SIDE or a.shape[0] * a.shape[1] > MAX_WRITE_PIXELS:
        raise WavlightError(f"{path}: an image of {a.shape[1]}x{a.shape[0]} pixels is too large to write (at most "
                            f"{MAX_WRITE_SIDE} a side and {MAX_WRITE_PIXELS} pixels, "
                            f"{MAX_WRITE_PIXELS * 12 >> 30} GiB as float RGB)")
    return a


def _rows(height: int, width: int):
    """Strips [y0, y1) of about STRIP_BYTES of float32 RGB."""
    step = max(1, STRIP_BYTES // (width * 12))
    return [(y, min(y + step, height)) for y in range(0, height, step)]


def _strip(image: np.ndarray, y0: int, y1: int, ext: str) -> np.ndarray:
    """Rows y0..y1-1 as the pixels the format gets (contiguous)."""
    # contiguous and aligned: OpenImageIO refuses an unaligned buffer ("buffer is wrong size"), as
    # numpy gives for an array unpickled from a byte offset (a dask worker's image, at some sizes)
    px = np.require(image[y0:y1], np.float32, ["C_CONTIGUOUS", "ALIGNED"])
    if ext in DISPLAY:
        return _srgb8(px)
    if ext == ".hdr":   # RGBE has no sign
        return np.maximum(px, np.float32(0.0))
    return px


def _write_temporary(path: str, image) -> str:
    """Check the image and the target, write the pixels to a temporary file beside the target
    and return its name (removed again if anything fails)."""
    import OpenImageIO as oiio

    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise WavlightError(f"{path}: unsupported output format {ext or '(none)'!r} "
                            f"(use {', '.join(FORMATS)})")
    image = _check_pixels(path, image)
    height, width = image.shape[:2]
    strips = _rows(height, width)
    for y0, y1 in strips:   # before any file exists; a strip at a time (no whole-image mask)
        part = image[y0:y1]
        if part.dtype.kind == "f" and not np.isfinite(part).all():
            raise WavlightError(f"{path}: refusing to write an image with NaN or Inf pixels")
        if part.dtype != np.float32 and part.size and np.abs(part).max() > np.finfo(np.float32).max:
            raise WavlightError(f"{path}: refusing to write an image with values beyond float32's range "
                                "(they would become Inf)")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise WavlightError(f"{path}: folder {folder} does not exist")
    if os.path.isdir(path):
        raise WavlightError(f"{path}: is a folder")
    try:
        fd, tmp = temporary(path)
    except OSError as e:
        raise WavlightError(f"{path}: cannot write ({e.strerror})") from None
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    try:
        out = oiio.ImageOutput.create(tmp)
        if out is None:
            raise WavlightError(f"{path}: cannot create writer ({oiio.geterror().strip()})")
        spec = oiio.ImageSpec(width, height, 3, oiio.UINT8 if ext in DISPLAY else oiio.FLOAT)
        ok = out.open(tmp, spec)
        err = "" if ok else out.geterror()
        if ok and len(strips) == 1:
            ok = out.write_image(_strip(image, 0, height, ext))
            # a writer may report a failed write (a full disk) only in its error text, while
            # write_image and close return True (OpenImageIO's PNG writer does): both count
            err = out.geterror()
        elif ok:
            for y0, y1 in strips:
                ok = out.write_scanlines(y0, y1, 0, _strip(image, y0, y1, ext))
                err = out.geterror()
                if not ok or err:
                    break
        ok = out.close() and ok
        err = (err + " " + out.geterror()).strip()
        if not ok or err:
            raise WavlightError(f"{path}: write failed ({_first_line(err)})")
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes files private; outputs get the usual mode
        return tmp
    except OSError as e:
        _remove([tmp])
        raise WavlightError(f"{path}: cannot write ({e.strerror or e})") from None
    except BaseException:
        _remove([tmp])
        raise


def _first_line(err: str) -> str:
    line = err.splitlines()[0].strip() if err.strip() else "unknown error"
    return line if len(line) <= 200 else line[:197] + "..."
