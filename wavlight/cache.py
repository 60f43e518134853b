"""wavlight's cache folder: compiled kernels, OpenCL driver lists, downloaded data.

``platformdirs.user_cache_dir("wavlight")`` (``$XDG_CACHE_HOME/wavlight``, by default
``~/.cache/wavlight`` on Linux), one sub-folder per kind of content. Everything in it can be
deleted at any time; it is made again when needed.
"""
from __future__ import annotations

from pathlib import Path


def cache_root() -> Path:
    """The cache folder itself (not created)."""
    import platformdirs

    return Path(platformdirs.user_cache_dir("wavlight"))


def cache_dir(kind: str) -> Path:
    """The cache sub-folder `kind`, created if missing (OSError when it cannot be)."""
    folder = cache_root() / kind
    folder.mkdir(parents=True, exist_ok=True)
    return folder
