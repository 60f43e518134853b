"""Errors that wavlight reports to users as one line (the CLI exits with code 2)."""
from __future__ import annotations

import math
import numbers

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


# ----------------------------------------------------------------------------- argument checks
def shown(value) -> str:
    """A short one-line description of a bad argument for a message (never an array's repr)."""
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape} and dtype {value.dtype}"
    text = " ".join(repr(value).split())
    return text if len(text) <= 60 else f"{text[:57]}..."


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
