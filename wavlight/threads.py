"""The size of wavlight's thread pools: renders, bakes and unbiased frames.

numpy, embree and OpenCL release the GIL, so threads overlap one tile's numpy and embree work
with another's wait for the device: a pool has two threads per core unless told otherwise
(measured 4-13% faster than one per core on 2 cores, docs/decisions/tile-threads.md). Images do
not depend on the number of threads.
"""
from __future__ import annotations

import os

#: a pool's threads per core unless a caller says otherwise
THREADS_PER_CORE = 2
#: the most threads a caller may ask for (``threads=`` of render_full, RayTracer, experiments)
MAX_THREADS = 4096


def default_threads(per_core: int = THREADS_PER_CORE) -> int:
    """The threads of a pool that is not given its size: ``per_core`` per core (``os.cpu_count``)."""
    return per_core * (os.cpu_count() or 1)
