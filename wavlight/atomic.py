"""Atomic writes: a file appears complete and readable, or not at all.

Every file wavlight writes (images, bake files, an experiment's records and charts, the
animations of turntables and orbits) goes through :func:`atomic_files` (or :func:`atomic_write` for one file):

1. a temporary file is made **in the destination folder** (a rename never crosses file
   systems), named ``.wavlight-<pid>.<host>-<target's name>.<random><ext>``
   (:func:`temporary`), so that :func:`remove_stale_temporaries` knows whose it is;
2. the caller's writer fills it (by name);
3. the data is flushed to the disk (``os.fsync``), and the file is checked: not empty, and the
   caller's ``check`` (its size, or that it reads back) finds nothing wrong. Some writers
   report a full disk nowhere (OpenImageIO's PNG and HDR writers leave an empty file behind
   and return success): this check is what catches them;
4. only then is it given the usual mode (``0666 & ~umask``) and renamed over the target
   (``os.replace``), every target of the call after every file passed.

On any error every temporary of the call is removed and a one-line
:class:`~wavlight.errors.WavlightError` names the target (an OSError becomes ``PATH: cannot
write (No space left on device)``); the previous target, if any, is untouched. A temporary that
a killed process (SIGKILL, a power cut) left behind is removed by the next successful write
into that folder (its pid names no running process on this machine). SIGTERM while a write is
under way removes the temporaries, as Ctrl-C (SIGINT) does.
"""
from __future__ import annotations

import contextlib
import hashlib
import os
import re
import shutil
import signal
import tempfile
import threading

from .errors import WavlightError, one_line

TEMPORARY_PREFIX = ".wavlight-"
#: .wavlight-<pid>.<host>-<target's name>.<random><ext>: whose it is, for remove_stale_temporaries
_TEMPORARY = re.compile(r"^\.wavlight-(\d+)\.([0-9a-f]{8})-(.*)\.[A-Za-z0-9_]{6,}(\.[A-Za-z0-9]+)?$")


def host_id() -> str:
    """8 hex digits naming this machine (a folder may be shared with writers on others)."""
    return hashlib.sha1(os.uname().nodename.encode()).hexdigest()[:8]


def temporary(target, suffix: str | None = None) -> tuple[int, str]:
    """(fd, name) of a new temporary file beside ``target``, named
    ``.wavlight-<pid>.<host>-<target's name>.<random><suffix>`` (suffix: the target's
    extension), so that :func:`remove_stale_temporaries` can tell whose it is. Also the
    scratch files of long writes (a bake's entries) are made here, beside their output."""
    target = os.fspath(target)
    folder = os.path.dirname(os.path.abspath(target))
    base = os.path.basename(target)
    ext = os.path.splitext(base)[1] if suffix is None else suffix
    return tempfile.mkstemp(prefix=f"{TEMPORARY_PREFIX}{os.getpid()}.{host_id()}-{base[:100]}.", suffix=ext,
                            dir=folder)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True   # another user's process (or not a pid we can ask about): keep its file
    return True


def remove_stale_temporaries(folder) -> list:
    """Remove from ``folder`` the temporaries that killed writers left (SIGKILL, a power cut):
    files named by :func:`temporary` on this machine whose pid is no running process. A live
    writer's file, or another machine's, is never touched. Returns the names removed."""
    removed = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    host = host_id()
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


def check_target(path, what: str = "a file") -> None:
    """A one-line WavlightError, before any work, when ``path`` cannot be written atomically:
    it is a folder, its folder does not exist or cannot be written, or it is a file that is
    read-only. (The rename would replace a read-only file all the same: refused for the
    caller that cannot write it or where it has no write permission at all, also for root.)"""
    path = os.fspath(path)
    if os.path.isdir(path):
        raise WavlightError(f"{path}: is a folder, not {what}")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise WavlightError(f"{path}: no folder {folder}")
    if not os.access(folder, os.W_OK):
        raise WavlightError(f"{path}: cannot write into {folder}")
    if os.path.isfile(path) and (not os.access(path, os.W_OK) or not os.stat(path).st_mode & 0o222):
        raise WavlightError(f"{path}: the file exists and is read-only")


def free_bytes(path) -> int | None:
    """Bytes that can still be written in the folder of ``path`` (None where unknown)."""
    try:
        return shutil.disk_usage(os.path.dirname(os.path.abspath(os.fspath(path)))).free
    except OSError:
        return None


def check_room(path, nbytes: int) -> None:
    """A one-line WavlightError, before any work, when the folder of ``path`` has less than
    ``nbytes`` free (a lower bound of what the write will need)."""
    free = free_bytes(path)
    if free is not None and free < nbytes:
        raise WavlightError(f"{path}: no room to write it ({_size(free)} free in "
                            f"{os.path.dirname(os.path.abspath(os.fspath(path)))}, at least {_size(nbytes)} needed)")


def _size(n: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} bytes"


class Terminated(SystemExit):
    """SIGTERM while :class:`terminate_as_exit` holds: the temporaries and scratch files are
    removed on the way out (exit code 143)."""


class terminate_as_exit:
    """While writing, or while a command runs (on the main thread only, where signal handlers run,
    and only while SIGTERM has its default action): SIGTERM raises :class:`Terminated`
    (SystemExit(128 + 15)) instead of ending the process at once, so that no temporary or scratch
    file is left behind; the default is restored afterwards."""

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
        raise Terminated(128 + signum)

    def __exit__(self, *exc):
        if self.previous is not None:
            signal.signal(signal.SIGTERM, self.previous)
        return False


def remove(paths) -> None:
    """Remove files that may already be gone."""
    for p in paths:
        try:
            os.unlink(p)
        except FileNotFoundError:
            pass
        except OSError:
            pass


def _sync(path: str) -> None:
    """Flush a written file's data to the disk (where a full disk or an I/O error that the
    writer's own buffered writes hid comes out)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _sync_folder(folder: str) -> None:
    """Make the renames durable (where the file system allows a folder to be synced)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _cannot_write(path: str, e: OSError) -> WavlightError:
    return WavlightError(f"{path}: cannot write ({e.strerror or one_line(e)})")


@contextlib.contextmanager
def atomic_files(targets, checks=None, suffixes=None):
    """Write several files all or nothing: yields the names of temporaries beside the
    ``targets`` (in that order) for the caller to write; when the block ends without an error,
    each is flushed to the disk and checked, then all are renamed over their targets.

    ``checks``: per target None or ``check(temporary) -> problem or None`` (a one-line reason
    the written file is unusable: the wrong size, not readable back); every file must also be
    non-empty. ``suffixes``: per target the temporary's extension (default: the target's, which
    some writers read to choose a format). Errors: module docstring."""
    targets = [os.fspath(t) for t in targets]
    checks = list(checks) if checks is not None else [None] * len(targets)
    suffixes = list(suffixes) if suffixes is not None else [None] * len(targets)
    temps = []
    path = targets[0] if targets else ""
    with terminate_as_exit():
        try:
            for path, suffix in zip(targets, suffixes):
                fd, tmp = temporary(path, suffix)
                os.close(fd)
                temps.append(tmp)
            yield list(temps)
            umask = os.umask(0)
            os.umask(umask)
            for path, tmp, check in zip(targets, temps, checks):
                _sync(tmp)
                size = os.path.getsize(tmp)
                problem = "the written file is empty" if size == 0 else check(tmp) if check else None
                if problem:
                    raise WavlightError(f"{path}: write failed ({problem}; is the disk full?); nothing written")
                os.chmod(tmp, 0o666 & ~umask)   # mkstemp makes files private; outputs get the usual mode
            for path, tmp in zip(targets, temps):
                os.replace(tmp, path)
        except OSError as e:
            remove(temps)
            raise _cannot_write(path, e) from None
        except MemoryError:
            remove(temps)
            raise WavlightError(f"{path}: not enough memory to write it") from None
        except BaseException:
            remove(temps)
            raise
    for folder in {os.path.dirname(os.path.abspath(p)) for p in targets}:
        _sync_folder(folder)
        remove_stale_temporaries(folder)


@contextlib.contextmanager
def atomic_write(target, check=None, suffix: str | None = None):
    """Write one file atomically (:func:`atomic_files`): yields the temporary's name.

        with atomic_write("turntable.png", check=frames_readable) as tmp:
            first.save(tmp, format="PNG", save_all=True, ...)
    """
    with atomic_files([target], [check], [suffix]) as temps:
        yield temps[0]


def size_is(nbytes: int):
    """A ``check`` for :func:`atomic_files`: the file holds exactly ``nbytes``."""
    def check(tmp):
        size = os.path.getsize(tmp)
        return None if size == nbytes else f"{size} bytes written of {nbytes}"
    return check
