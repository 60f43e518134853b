"""wavlight's cache folder: compiled kernels, OpenCL driver lists, downloaded data.

``platformdirs.user_cache_dir("wavlight")`` (``$XDG_CACHE_HOME/wavlight``, by default
``~/.cache/wavlight`` on Linux), one sub-folder per kind of content. Everything in it can be
deleted at any time; it is made again when needed.
"""
from __future__ import annotations

from pathlib import Path


def cache_dir(kind: str) -> Path:
    """The cache sub-folder `kind`, created if missing (OSError when it cannot be)."""
    import platformdirs

    folder = Path(platformdirs.user_cache_dir("wavlight")) / kind
    folder.mkdir(parents=True, exist_ok=True)
    return folder
