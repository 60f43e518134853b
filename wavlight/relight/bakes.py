"""The bake for the one factor its frames vary (Chen & Gao sec. 2.2): the lighting or one object
(per-pixel transfer, :func:`wavlight.relight.bake.bake`), or the view (a surface cache,
:func:`wavlight.relight.view_bake.bake_view`). This is ``wavlight.bake``, the call ``wavlight bake``
makes: its keywords, their defaults and ranges are the records of
:data:`wavlight.relight.settings.BAKE`."""
from __future__ import annotations

import os

from ..errors import ArgumentError, shown
from ..scene import load_scene
from .bake import bake as bake_pixels
from .settings import BAKE
from .view_bake import bake_view

#: the factors a bake may vary
VARY = BAKE["vary"].values


def bake(scene, output=None, width=None, height=None, spp=None, levels=None,
         tolerance: float = BAKE["tolerance"].default, bits: int = BAKE["bits"].default, terms=None, priority=None,
         seed: int = BAKE["seed"].default, threads=None, progress=None, backend: str = "opencl", dask_address=None,
         points=None, vary: str = BAKE["vary"].default, object=None, static_spp: int = BAKE["static_spp"].default,
         density=None):
    """Bake ``scene`` (a Scene or a scene file) for frames that vary ``vary`` and write it to
    ``output`` (default: a temporary file the Transfer owns); returns the
    :class:`wavlight.relight.Transfer`.

    ``vary="lighting"`` (default) and ``vary="object"`` (with ``object``, a name or an index) bake
    each pixel's transfer for the scene's camera: :func:`wavlight.relight.bake.bake` gives the
    meaning of every other argument (``spp``, ``levels``, ``terms``, ``priority`` and ``points``
    left None are chosen from the scene by pilot bakes). ``vary="view"`` bakes T1 = L V cos per
    point of a surface cache of ``density`` points per unit area for frames from any camera
    (:func:`wavlight.relight.view_bake.bake_view`). There width, height, spp, terms and priority do
    not apply, and the bake runs locally."""
    where = "relight.bake"
    if vary not in VARY:
        raise ArgumentError(f"{where}: vary must be one of {' | '.join(VARY)}, got {shown(vary)}")
    if isinstance(scene, (str, os.PathLike)):
        scene = load_scene(scene)
    if vary != "view":
        if density is not None:
            raise ArgumentError(f"{where}: density sets the surface cache of a bake with vary='view'")
        return bake_pixels(scene, output, width=width, height=height, spp=spp, levels=levels, tolerance=tolerance,
                           bits=bits, terms=terms, priority=priority, seed=seed, threads=threads, progress=progress,
                           backend=backend, dask_address=dask_address, points=points, vary=vary, object=object,
                           static_spp=static_spp)
    if object is not None:
        raise ArgumentError(f"{where}: an object is given only with vary='object'")
    if dask_address is not None:
        raise ArgumentError(f"{where}: a view bake runs locally (no Dask cluster)")
    return bake_view(scene, output, levels=levels, tolerance=tolerance, bits=bits, seed=seed, threads=threads,
                     progress=progress, backend=backend, points=points, density=density)
