"""wavlight's thread pools: their size (renders, bakes and unbiased frames), and a pool whose
calls stop between their passes when the caller stops waiting (:func:`map_until_stopped`).

numpy, embree and OpenCL release the GIL, so threads overlap one tile's numpy and embree work
with another's wait for the device: a pool has two threads per core unless told otherwise
(measured 4-13% faster than one per core on 2 cores, docs/decisions/tile-threads.md). Images do
not depend on the number of threads.
"""
from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor, as_completed

#: a pool's threads per core unless a caller says otherwise
THREADS_PER_CORE = 2
#: the most threads a caller may ask for (``threads=`` of render_full, RayTracer, experiments)
MAX_THREADS = 4096


def default_threads(per_core: int = THREADS_PER_CORE) -> int:
    """The threads of a pool that is not given its size: ``per_core`` per core (``os.cpu_count``)."""
    return per_core * (os.cpu_count() or 1)


def map_until_stopped(function, items, threads: int) -> None:
    """``function(item, stop)`` for each of ``items`` on a pool of ``threads`` threads (results
    dropped; the exception of the first call that fails is raised as soon as it ends). ``stop``,
    a threading.Event, is set as soon as the calling thread stops waiting (an exception of a
    call, Ctrl-C, SIGTERM): the items not begun are dropped, and a call under way returns at its
    next check of ``stop`` (between its passes) instead of finishing its item, so that the
    command stops in a pass's time rather than in an item's (an unbiased frame's block at any
    spp)."""
    stop = threading.Event()
    with ThreadPoolExecutor(threads) as pool:
        futures = [pool.submit(function, item, stop) for item in items]
        try:
            for future in as_completed(futures):   # a failure as soon as it happens, in any item
                future.result()
        except BaseException:
            stop.set()
            for future in futures:
                future.cancel()
            raise
