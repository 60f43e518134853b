"""Ray queries (wavlight/raytrace.py): embree's answers and the trimesh fallback's agree."""
import sys

import numpy as np
import trimesh

from wavlight import raytrace
from wavlight.raytrace import EmbreeQueries, RayTracer, TrimeshQueries


def _rays(n, seed):
    """Rays from a sphere of radius 4 towards points of the cube [-1.5, 1.5]^3 (about half hit)."""
    rng = np.random.default_rng(seed)
    o = rng.normal(size=(n, 3))
    o *= 4 / np.linalg.norm(o, axis=1, keepdims=True)
    d = rng.uniform(-1.5, 1.5, (n, 3)) - o
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def test_trimesh_fallback_answers_as_embree():
    """Closest hits (face, distance, barycentrics) and occlusion of random rays through a
    sphere and a box, by both query classes; rays that graze an edge may pick either face."""
    mesh = trimesh.util.concatenate([trimesh.creation.icosphere(3), trimesh.creation.box((1, 3, 0.5))])
    o, d = _rays(4000, 3)
    a = RayTracer(mesh.vertices, mesh.faces, queries=EmbreeQueries)
    b = RayTracer(mesh.vertices, mesh.faces, queries=TrimeshQueries)
    pa, ta, ua, va = a.intersect_uv(o, d)
    pb, tb, ub, vb = b.intersect_uv(o, d)
    assert (pa >= 0).sum() > 1000 and (pa < 0).sum() > 1000   # both kinds of ray are tested
    assert np.array_equal(pa >= 0, pb >= 0)
    same = pa == pb
    assert same.mean() > 0.995
    hit = pa >= 0
    np.testing.assert_allclose(ta[hit], tb[hit], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ua[same & hit], ub[same & hit], atol=1e-4)
    np.testing.assert_allclose(va[same & hit], vb[same & hit], atol=1e-4)
    assert np.array_equal(a.occluded(o, d), b.occluded(o, d))
    assert np.all(tb[~hit] == np.inf) and np.all(pb[~hit] == -1)


def test_without_embreex_the_fallback_is_used(monkeypatch):
    monkeypatch.setitem(sys.modules, "embreex", None)   # import embreex raises ImportError
    assert raytrace.default_queries() is TrimeshQueries
    monkeypatch.delitem(sys.modules, "embreex")
    assert raytrace.default_queries() is EmbreeQueries
