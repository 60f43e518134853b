"""The scene's visibility variance (wavlight.occlusion, the setup's pilot of shadow rays) and
the wavelet budget (candidates, slots) a render chooses from it."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import stats

import wavlight
from wavlight import occlusion, strategies
from wavlight.raytrace import RayTracer

from scenes_util import load

SKY = dict(procedural="sky")
SPHERE = dict(shape="sphere", center=[0.0, 0.0, 0.0], radius=1.0, subdivisions=3, material="m")
FLOOR = dict(shape="quad", center=[0.0, -1.0, 0.0], normal=[0.0, 1.0, 0.0], size=200.0, material="m")
LOOK_AT_SPHERE = dict(eye=[0.0, 0.5, 4.0], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0], fov_y=40.0)
LOOK_DOWN = dict(eye=[0.0, 2.0, 0.0], target=[0.0, -1.0, 0.0], up=[0.0, 0.0, -1.0], fov_y=60.0)


def _scene(tmp_path, objects, camera, width=40, height=30, **render):
    return load(tmp_path, render=dict(width=width, height=height, spp=2, strategy="wavelet", **render),
                camera=camera, environment=SKY, objects=objects,
                materials={"m": dict(type="ggx", roughness=0.2)})


def _variance(scene, tracer=None):
    tracer = tracer or RayTracer(scene.vertices, scene.faces)
    return occlusion.visibility_variance(scene, tracer, scene.width, scene.height)


class _RuleTracer:
    """The scene's own hits, but occlusion decided by a rule on the direction alone."""

    def __init__(self, tracer, rule):
        self.tracer, self.rule, self.rays = tracer, rule, 0

    def __getattr__(self, name):
        return getattr(self.tracer, name)

    def occluded(self, origins, dirs):
        self.rays += len(dirs)
        return self.rule(np.asarray(dirs, np.float64))


def test_nothing_in_shadow_is_zero(tmp_path):
    """A lone (convex) sphere, a lone floor seen from above and from below (its normal turned
    towards the viewer, so no direction goes through it), and a camera that sees nothing:
    exactly 0."""
    assert _variance(_scene(tmp_path, [SPHERE], LOOK_AT_SPHERE)) == 0.0
    assert _variance(_scene(tmp_path, [FLOOR], LOOK_DOWN)) == 0.0
    look_up = dict(LOOK_DOWN, eye=[0.0, -3.0, 0.0], target=[0.0, 0.0, 0.0])
    assert _variance(_scene(tmp_path, [FLOOR], look_up)) == 0.0
    assert _variance(_scene(tmp_path, [SPHERE], dict(LOOK_AT_SPHERE, target=[0.0, 0.5, 8.0]))) == 0.0


def test_all_blocked_is_zero(tmp_path):
    """A floor under a ceiling that covers its whole hemisphere: every ray blocked, no
    variance."""
    # (1e5 wide, 3.5 above the floor: a ray escapes below 7e-5 rad of elevation, about 5e-9
    # of cosine-distributed directions)
    ceiling = dict(FLOOR, center=[0.0, 2.5, 0.0], size=1e5)
    assert _variance(_scene(tmp_path, [dict(FLOOR, size=1e5), ceiling], LOOK_DOWN)) == 0.0


@pytest.mark.parametrize("cos_limit", [0.5, np.sqrt(0.5), 0.9, 0.2])
def test_estimate_is_consistent(tmp_path, cos_limit):
    """Directions within an angle of the floor's normal blocked by rule: cosine-distributed
    directions are blocked with probability b = 1 - cos_limit^2 (so the directions are
    cosine-distributed about the right normal), and the pilot's E[b (1 - b)] / E[1 - b]^2
    (per point b (1 - b) estimated as b^ (1 - b^) K / (K - 1)) is b / (1 - b) within 4
    standard errors: the delta method's, from each point's Binomial(K, b) count enumerated
    exactly (a ratio of means over the pilot's 1024 points, so its own bias, O(1/N), is far
    below that)."""
    scene = _scene(tmp_path, [FLOOR], LOOK_DOWN, width=32, height=32)
    tracer = _RuleTracer(RayTracer(scene.vertices, scene.faces), lambda d: d[:, 1] > cos_limit)
    got = _variance(scene, tracer)
    b = 1.0 - cos_limit ** 2
    k = occlusion.PILOT_DIRECTIONS
    n_points = occlusion.PILOT_SIDE ** 2
    assert tracer.rays == n_points * k   # every pilot camera ray hit the floor
    counts = np.arange(k + 1)
    x = (counts / k) * (1.0 - counts / k) * k / (k - 1)     # numerator per point
    y = 1.0 - counts / k                                    # visible share per point
    pmf = stats.binom.pmf(counts, k, b)
    mx, my = pmf @ x, pmf @ y
    vx, vy, cxy = pmf @ (x - mx) ** 2, pmf @ (y - my) ** 2, pmf @ ((x - mx) * (y - my))
    assert mx / my ** 2 == pytest.approx(b / (1 - b), rel=1e-12)
    # r = mx / my^2: dr/dmx = 1 / my^2, dr/dmy = -2 mx / my^3
    gx, gy = 1.0 / my ** 2, -2.0 * mx / my ** 3
    se = np.sqrt((gx ** 2 * vx + gy ** 2 * vy + 2 * gx * gy * cxy) / n_points)
    assert abs(got - b / (1 - b)) < 4 * se, (got, b / (1 - b), se)


@pytest.mark.parametrize("width, height", [(64, 16), (16, 64), (1000, 1), (32, 32)])
def test_pilot_grid_is_shaped_as_the_image(tmp_path, width, height):
    """About PILOT_SIDE^2 camera rays whatever the aspect ratio (a grid of round(32 sqrt(a))
    x round(32 / sqrt(a)) cells, at least one each way), every one of them hitting the floor
    below, each with PILOT_DIRECTIONS shadow rays."""
    scene = _scene(tmp_path, [dict(FLOOR, size=1e4)], dict(LOOK_DOWN, fov_y=20.0), width=width, height=height)
    tracer = _RuleTracer(RayTracer(scene.vertices, scene.faces), lambda d: d[:, 1] > 0.5)
    _variance(scene, tracer)
    a = width / height
    cells = max(1, round(32 * np.sqrt(a))) * max(1, round(32 / np.sqrt(a)))
    assert tracer.rays == cells * occlusion.PILOT_DIRECTIONS
    assert 0.5 * occlusion.PILOT_SIDE ** 2 <= cells <= 2 * occlusion.PILOT_SIDE ** 2


def test_mostly_blocked_light_counts_as_shadowed(tmp_path):
    """Light through a small opening (97% of the cosine-weighted hemisphere blocked at every
    point) is the most shadowed case, not the least: the relative variance, b / (1 - b) = 32
    in expectation, is far above the threshold."""
    scene = _scene(tmp_path, [FLOOR], LOOK_DOWN, width=32, height=32)
    tracer = RayTracer(scene.vertices, scene.faces)
    got = _variance(scene, _RuleTracer(tracer, lambda d: d[:, 1] < np.sqrt(0.97)))
    assert got > 10 * strategies.SHADOWED_VARIANCE


def test_object_on_floor_is_shadowed(tmp_path):
    """A sphere on a floor (the floor's contact shadow, the sphere's lower half facing the
    floor) and the built-in default scene count as shadowed."""
    on_floor = _scene(tmp_path, [SPHERE, FLOOR], LOOK_AT_SPHERE)
    assert _variance(on_floor) > strategies.SHADOWED_VARIANCE
    default = wavlight.load_scene(str(Path(__file__).parents[1] / "scenes" / "default.toml"))
    assert _variance(default) > strategies.SHADOWED_VARIANCE


@pytest.mark.slow
def test_render_chooses_the_budget_from_the_scene(tmp_path):
    """Unset candidates and slots come from AUTO_BUDGET by the scene's visibility variance,
    which --json reports; what is given wins, and a render that has nothing left to choose
    runs no pilot (visibility_variance None)."""
    (tmp_path / "lone").mkdir()
    (tmp_path / "shadowed").mkdir()
    lone = _scene(tmp_path / "lone", [SPHERE], LOOK_AT_SPHERE)
    shadowed = _scene(tmp_path / "shadowed", [SPHERE, FLOOR], LOOK_AT_SPHERE)

    def run(scene, **kw):
        s = wavlight.render_full(scene, spp=1, width=8, height=6, **kw).stats
        return s["wavelet_candidates"], s["wavelet_slots"], s["visibility_variance"]

    m, s, v = run(lone)
    assert (m, s) == strategies.AUTO_BUDGET["unshadowed"] and v == 0.0
    m, s, v = run(shadowed)
    assert (m, s) == strategies.AUTO_BUDGET["shadowed"] and v > strategies.SHADOWED_VARIANCE
    assert run(shadowed, wavelet_candidates=12)[:2] == (12, strategies.AUTO_BUDGET["shadowed"][1])
    assert run(shadowed, wavelet_slots=2)[:2] == (strategies.AUTO_BUDGET["shadowed"][0], 2)
    assert run(shadowed, wavelet_candidates=12, wavelet_slots=2) == (12, 2, None)
    assert run(shadowed, wavelet_candidates=0) == (0, 2, None)
    assert "visibility_variance" not in wavlight.render_full(lone, spp=1, width=8, height=6, strategy="mis").stats


def test_fit_to_visibility_refuses_bad_values_and_late_calls():
    """A variance that is not a finite number >= 0 is refused in one line, and so is a call
    after prepare(), whose tables and kernels are built for the budget it saw."""
    from wavlight.errors import ArgumentError
    from wavlight.envmap import Environment

    for bad in (float("nan"), float("inf"), -0.1, "0.2", None):
        with pytest.raises(ArgumentError, match="variance must be a finite number"):
            strategies.make("wavelet").fit_to_visibility(bad)
    strat = strategies.make("wavelet")
    strat.fit_to_visibility(0.0)
    assert (strat.candidates, strat.slots) == strategies.AUTO_BUDGET["unshadowed"]
    strat.prepare(Environment(np.ones((8, 16, 3), np.float32)))
    with pytest.raises(ArgumentError, match="before prepare"):
        strat.fit_to_visibility(1.0)
