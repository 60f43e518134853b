"""How much of what the camera sees lies in partial shadow: a pilot of shadow rays at setup.

The wavelet strategy's resampling estimator (docs/strategies.md) spends its work on two
things: candidates (walks, no rays) and slots (directions that get a shadow ray). With its
control variate an unshadowed point's estimate is the candidates' own unshadowed estimate,
exact in the slots, so there only candidates reduce the variance; where a point's lighting is
partly blocked, the slots' visibility carries the rest. :func:`visibility_variance` measures
which case a scene is, so that the strategy can spend on the one it needs
(:meth:`wavlight.strategies.WaveletStrategy.fit_to_visibility`).

The pilot: camera rays through the centres of a grid of about ``side`` x ``side`` cells over
the image, shaped as the image, and at every hit ``directions`` cosine-distributed directions
about the face normal turned towards the viewer, traced as shadow rays from the renderer's own
offset origins (:meth:`RayTracer.shadow_offsets`). The directions come from a fixed
generator, so the figure (and the choice made from it) does not depend on the render's seed
or spp. About 1024 camera rays and at most 16 times as many shadow rays: about 3 ms on the
scenes in scenes/ (the ray-tracing structure is built before, with the RayTracer).
"""
from __future__ import annotations

import numpy as np

from . import warp
from .camera import camera_rays
from .raytrace import RayTracer

PILOT_SIDE = 32
PILOT_DIRECTIONS = 16
_PILOT_SEED = 0x5EED


def visibility_variance(scene, tracer: RayTracer, width: int, height: int, side: int = PILOT_SIDE,
                        directions: int = PILOT_DIRECTIONS) -> float:
    """The relative variance of visibility over what the camera sees: E[b (1 - b)] / E[1 - b]^2,
    b a pilot hit point's blocked share of its cosine-distributed directions (module
    docstring), the means over the hits. 0 where nothing is shadowed, the camera hits nothing
    or everything it sees is fully blocked; it grows as shadows cover more of what is lit,
    and without bound where light arrives through small openings (a room lit through a
    slit). Relative, as relMSE is: where most of the light is blocked, what gets through
    is noisy against the little that is seen. b (1 - b) per point is estimated without bias
    from its ``directions`` rays (times K / (K - 1))."""
    aspect = width / height   # about side^2 cells, shaped as the image
    gw, gh = max(1, round(side * np.sqrt(aspect))), max(1, round(side / np.sqrt(aspect)))
    gx, gy = np.meshgrid(np.arange(gw), np.arange(gh))
    # the pilot cells' centres in the render's own pixel coordinates
    px = ((gx.ravel() + 0.5) * width / gw).astype(np.float32)
    py = ((gy.ravel() + 0.5) * height / gh).astype(np.float32)
    eye, d = camera_rays(scene, px, py, np.zeros((len(px), 2), np.float32), width, height)
    prim, t = tracer.intersect(eye, d)
    hit = np.flatnonzero(prim >= 0)
    if len(hit) == 0 or directions < 2:
        return 0.0
    normal, _, origin = tracer.surface(scene.camera.eye, d[hit], t[hit], prim[hit])
    u = np.random.default_rng(_PILOT_SEED).random((len(hit) * directions, 2))
    normal = np.repeat(normal.astype(np.float64), directions, axis=0)
    tangent, bitangent = warp.frame(normal)
    wi = warp.to_world(warp.square_to_cosine_hemisphere(u), tangent, bitangent, normal).astype(np.float32)
    blocked = tracer.occluded(np.repeat(origin, directions, axis=0), wi)
    b = blocked.reshape(len(hit), directions).mean(axis=1)
    visible = float(np.mean(1.0 - b))
    if visible == 0.0:
        return 0.0
    return float(np.mean(b * (1.0 - b)) * directions / (directions - 1)) / visible ** 2
