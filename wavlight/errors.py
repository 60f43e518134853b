"""Errors that wavlight reports to users as one line (the CLI exits with code 2)."""
from __future__ import annotations

import errno
import math
import numbers
import os
import stat

import numpy as np


class WavlightError(Exception):
    """Bad input or an unusable system: the message is meant for the user as is."""


class SceneError(WavlightError):
    """A problem in a scene file, naming the file and the key."""

    def __init__(self, path, key: str, message: str):
        self.path, self.key = str(path), key
        super().__init__(f"{path}: {key}: {message}" if key else f"{path}: {message}")


class SanitisedInputWarning(UserWarning):
    """Bad input that was repaired rather than refused (NaN, Inf or negative texels set to 0,
    degenerate triangles removed): the result is usable but not what the file asked for.
    The CLI finishes its work and then exits with code 3 (:data:`SANITISED_EXIT_CODE`)."""


#: the CLI's exit code after a run that completed on sanitised input
SANITISED_EXIT_CODE = 3


class ArgumentError(WavlightError, ValueError):
    """A bad argument to a library function, named with the function; also a ValueError, so
    existing ``except ValueError`` callers keep working."""


def one_line(message, limit: int | None = None) -> str:
    """A message (or an exception's) as one line: its lines joined with '; ' (libraries such as
    OpenImageIO answer on several), an empty one named by its type, cut to ``limit`` characters."""
    text = "; ".join(part.strip() for part in str(message).splitlines() if part.strip())
    if not text and isinstance(message, BaseException):
        text = type(message).__name__
    return text if limit is None or len(text) <= limit else text[:limit - 3] + "..."


def described(error: BaseException) -> str:
    """An exception as one line for a user: a WavlightError's message as it is, any other
    prefixed with its type (``OSError: ...``), so that a fault is told from bad input."""
    return one_line(error) if isinstance(error, WavlightError) else f"{type(error).__name__}: {one_line(error)}"


# ----------------------------------------------------------------------------- argument checks
#: The longest value a message shows (longer ones are cut, with their length).
SHOWN_CHARS = 80


def shown(value, limit: int = SHOWN_CHARS) -> str:
    """A short one-line description of a bad value for a message: its repr cut to ``limit``
    characters (a 10 MB list must not become a 10 MB line), never an array's repr. Safe on
    anything: a value whose repr fails or recurses is named by its type."""
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape} and dtype {value.dtype}"
    if isinstance(value, (list, tuple, dict, set, str, bytes)) and len(value) > 4 * limit:
        # the repr of a huge container is not built at all: its first items tell enough
        head = value[:limit] if isinstance(value, (list, tuple, str, bytes)) else list(value)[:limit]
        kind = type(value).__name__
        try:
            text = " ".join(repr(head).split())
        except Exception:
            text = kind
        unit = "characters" if isinstance(value, str) else "bytes" if isinstance(value, bytes) else "items"
        return f"{text[:limit - 3]}... ({kind} of {len(value)} {unit})"
    try:
        text = " ".join(repr(value).split())
    except Exception:   # RecursionError (deeply nested), a repr that raises
        return f"a {type(value).__name__}"
    return text if len(text) <= limit else f"{text[:limit - 3]}..."


def file_problem(path, want: str = "file") -> str | None:
    """Why ``path`` cannot be read as a regular file (``want="file"``) or used as a folder
    (``want="folder"``), as a short phrase for a message, or None when it can: "no such file",
    "is a folder", "is a FIFO, not a regular file" (opening one would wait for a writer),
    "is a symbolic link loop", "is a broken symbolic link to ...", "permission denied", ..."""
    try:
        path = os.fspath(path)
    except TypeError:
        return f"is not a path ({shown(path)})"
    if not isinstance(path, str) or not path:
        return "is not a path (empty)"
    if "\0" in path:
        return "is not a path (it holds a NUL character)"
    try:
        st = os.stat(path)
    except OSError as e:
        if e.errno == errno.ELOOP:
            return "is a symbolic link loop"
        if e.errno == errno.ENOENT:
            if os.path.islink(path):
                return f"is a broken symbolic link (to {shown(os.readlink(path))})"
            parent = os.path.dirname(os.path.abspath(path))
            return "no such file" if want == "file" or os.path.isdir(parent) else "no such folder"
        if e.errno == errno.ENOTDIR:
            return "no such file (a part of the path is not a folder)"
        if e.errno == errno.ENAMETOOLONG:
            return "is not a path (the name is too long)"
        if e.errno == errno.EACCES:
            return "permission denied"
        return f"cannot be read ({e.strerror})"
    mode = st.st_mode
    if want == "folder":
        return None if stat.S_ISDIR(mode) else "is not a folder"
    if stat.S_ISDIR(mode):
        return "is a folder, not a file"
    if not stat.S_ISREG(mode):
        kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode)
                else "a character device" if stat.S_ISCHR(mode) else "a block device" if stat.S_ISBLK(mode)
                else "not a regular file")
        return f"is {kind}, not a regular file"
    if not os.access(path, os.R_OK):
        return "permission denied"
    return None


def check_file(path, what: str = "") -> str:
    """``path`` (as a str) if it is a readable regular file, else a one-line WavlightError
    naming it and saying why (:func:`file_problem`)."""
    problem = file_problem(path)
    if problem is not None:
        raise WavlightError(f"{what + ': ' if what else ''}{path}: {problem}")
    return os.fspath(path)


def check_int(where: str, name: str, value, lo=None, hi=None) -> int:
    """value as an int in [lo, hi] (either bound optional); bools and 2.7 are refused."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise ArgumentError(f"{where}: {name} must be an integer, got {shown(value)}")
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        bound = (f"between {lo} and {hi}" if lo is not None and hi is not None
                 else f"at least {lo}" if lo is not None else f"at most {hi}")
        raise ArgumentError(f"{where}: {name} must be {bound}, got {value}")
    return int(value)


def check_number(where: str, name: str, value, lo=None, hi=None) -> float:
    """value as a finite float in [lo, hi] (either bound optional); NaN, Inf and bools refused."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ArgumentError(f"{where}: {name} must be a number, got {shown(value)}")
    try:
        value = float(value)
    except OverflowError:  # an int beyond float's range
        value = math.inf
    if not math.isfinite(value) or (lo is not None and value < lo) or (hi is not None and value > hi):
        bound = (f" in [{lo:g}, {hi:g}]" if lo is not None and hi is not None
                 else f" >= {lo:g}" if lo is not None else f" <= {hi:g}" if hi is not None else "")
        raise ArgumentError(f"{where}: {name} must be a finite number{bound}, got {value}")
    return value


def check_degrees(where: str, name: str, value) -> float:
    """A finite angle in degrees, reduced exactly modulo 360 (math.fmod in float64: the sign of
    ``value``, magnitude below 360), so that no later step (radians, a float32 cast, a turntable's
    steps added to it) loses it; NaN, Inf and bools refused as by :func:`check_number`."""
    return math.fmod(check_number(where, name, value), 360.0)


def check_real(where: str, name: str, value, finite: bool = False) -> np.ndarray:
    """value as a numpy array of real numbers (bool, int or float dtype), optionally all finite."""
    try:
        a = np.asarray(value)
    except (TypeError, ValueError):  # ragged nested lists
        raise ArgumentError(f"{where}: {name} must be an array of numbers, got {shown(value)}") from None
    if a.dtype.kind not in "biuf":
        raise ArgumentError(f"{where}: {name} must be an array of real numbers, got "
                            f"{type(value).__name__} of dtype {a.dtype}")
    if finite and a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        bad = a.size - int(np.count_nonzero(np.isfinite(a)))
        raise ArgumentError(f"{where}: {name} must be finite, got NaN or Inf in {bad} of {a.size} entries")
    return a


def check_integers(where: str, name: str, value, size: int | None = None) -> np.ndarray:
    """value as an int64 array (integer dtype; empty lists allowed), with size: indices in [0, size)."""
    a = check_real(where, name, value)
    if a.size == 0:
        return a.astype(np.int64)
    if a.dtype.kind not in "iu":
        raise ArgumentError(f"{where}: {name} must be integers, got dtype {a.dtype}")
    if size is not None:
        lo, hi = a.min(), a.max()
        if lo < 0 or hi >= size:
            raise ArgumentError(f"{where}: {name} must be in [0, {size}), got {lo if lo < 0 else hi}")
    return a.astype(np.int64, copy=False)
