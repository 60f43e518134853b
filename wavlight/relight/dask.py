"""Baking on a dask.distributed cluster: each block is the pure function
:func:`wavlight.relight.bake.bake_block_task` of the scene file (checked by its content hash),
the settings and the tile, so a cluster's bake is identical to a local one; this process
writes the file as the blocks arrive."""
from __future__ import annotations

from ..cluster import connect
from ..errors import WavlightError


def bake_on_cluster(address: str, scene, settings, tiles, task, collect, without=None) -> None:
    """Submit ``task`` (a module-level function of one dict, :func:`wavlight.relight.bake.bake_block_task`)
    for every tile to the scheduler at ``address`` and hand each result to ``collect``."""
    import os

    client = connect(address)
    try:
        from distributed import as_completed

        path = os.path.abspath(scene.path)
        futures = [client.submit(task, {"scene_path": path, "content_hash": scene.content_hash,
                                        "settings": settings, "tile": tile, "without": without}, pure=False)
                   for tile in tiles]
        for future in as_completed(futures):
            try:
                collect(future.result())
            except WavlightError:
                raise
            except Exception as e:   # a worker's error, as one line
                raise WavlightError(f"dask {address}: a block failed on a worker: {type(e).__name__}: {e}") from None
    finally:
        client.close()
