"""End-to-end rendering tests against independently computed expectations.

Every expected value is derived here from ``shared/docs/scene-format.md`` (lat-long formula,
pinhole camera, BRDF formulas), never from wavlight's own output or code. Monte Carlo
results are compared within their reported standard errors (``RenderResult.stderr``) with a
Bonferroni threshold over the pixels checked and an aggregate check over all of them
(see ``scenes_util.check_estimates``). Seeds are fixed.
"""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest

import wavlight
from scenes_util import (Pinhole, camera_of, check_estimates, dir_from_uv, line_distance, load,
                         ray_sphere, rot_y, texel_dir, texel_radius, uv_from_dir, write_env)

ALL_STRATEGIES = ("uniform", "cosine", "bsdf", "light", "mis", "mis_comp", "wavelet")


def test_strategy_list_is_the_documented_one():
    assert set(ALL_STRATEGIES) <= set(wavlight.STRATEGIES)


def _render(scene, strategy, spp, seed=1, **kw):
    r = wavlight.render_full(scene, spp=spp, strategy=strategy, seed=seed, **kw)
    assert r.image.shape == (scene.height, scene.width, 3)
    assert r.stderr.shape == r.image.shape
    return r


def _inradius(scene, centre):
    """Smallest distance from centre to the planes of the scene's faces (a convex mesh's inradius)."""
    v = scene.vertices.astype(np.float64)
    f = scene.faces
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return float(np.abs(np.einsum("ij,ij->i", n, v[f[:, 0]] - centre)).min())


def _sphere_masks(cam: Pinhole, centre, r_in, r_out):
    """(inner, background): pixels entirely on the inscribed sphere; pixels entirely off the
    circumscribed sphere. The image of a sphere is convex, so four corners inside suffice."""
    corners = cam.pixel_rays(1)
    inner = np.all(np.isfinite(ray_sphere(cam.eye, corners, centre, r_in)), axis=-1)
    centre_rays = cam.centre_rays()
    pix_radius = np.arccos(np.clip(np.einsum("hwkc,hwc->hwk", corners, centre_rays), -1, 1)).max(-1)
    to_c = np.asarray(centre, np.float64) - cam.eye
    dist = np.linalg.norm(to_c)
    ang = np.arccos(np.clip(centre_rays @ (to_c / dist), -1, 1))
    background = ang > math.asin(r_out / dist) + pix_radius + 1e-3
    return inner, background


# ============================================================================= 1. white furnace
@pytest.fixture(scope="module")
def furnace(tmp_path_factory):
    d = tmp_path_factory.mktemp("furnace")
    env = write_env(d, "white.exr", np.ones((4, 8, 3)))
    albedo = [0.7, 0.45, 0.2]
    scene = load(d, render=dict(width=24, height=24, spp=64, seed=3),
                 camera=dict(eye=[0.3, 0.4, 3.5], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0], fov_y=40.0),
                 environment=dict(file=env),
                 # face normals: the identity holds for the geometric normal (with shading normals the
                 # directions between the shading and the geometric horizon carry no light)
                 objects=[dict(shape="sphere", center=[0.0, 0.0, 0.0], radius=1.0, subdivisions=5,
                               material="white", face_normals=True)],
                 materials={"white": dict(type="lambert", albedo=albedo)})
    cam = camera_of(scene)
    inner, background = _sphere_masks(cam, np.zeros(3), _inradius(scene, np.zeros(3)), 1.0)
    assert inner.sum() > 150 and background.sum() > 150
    return scene, np.array(albedo), inner, background


@pytest.mark.slow
@pytest.mark.parametrize("strategy", ALL_STRATEGIES)
def test_white_furnace_lambert_sphere(furnace, strategy):
    """L = albedo exactly under a constant environment of 1 (a convex object never shadows itself)."""
    scene, albedo, inner, background = furnace
    spp = 64
    r = _render(scene, strategy, spp)
    # background pixels see the environment directly: exactly 1, no noise
    assert np.all(r.image[background] == 1.0), r.image[background].min(axis=0)
    assert np.all(r.stderr[background] == 0.0)
    if strategy in ("cosine", "bsdf"):
        # lambert f cos / pdf is the constant albedo: zero variance, exact result
        assert np.all(r.stderr[inner] < 1e-6)
    check_estimates(r.image, r.stderr, albedo, inner, spp, label=f"furnace/{strategy}")


# ============================================================================= 2. ggx and phong albedo
def _gauss(n, lo, hi):
    x, w = np.polynomial.legendre.leggauss(n)
    return lo + (hi - lo) * (x + 1) / 2, w * (hi - lo) / 2


def _panels(edges, n):
    xs, ws = zip(*(_gauss(n, lo, hi) for lo, hi in zip(edges[:-1], edges[1:]) if hi > lo))
    return np.concatenate(xs), np.concatenate(ws)


def ggx_D(cos_h, alpha):
    """Trowbridge-Reitz: alpha^2 / (pi cos^4 (alpha^2 + tan^2)^2)."""
    c2 = cos_h * cos_h
    tan2 = (1 - c2) / c2
    return alpha * alpha / (math.pi * c2 * c2 * (alpha * alpha + tan2) ** 2)


def ggx_G1(cos_w, alpha):
    """Smith masking for GGX: 2 / (1 + sqrt(1 + alpha^2 tan^2)), 0 below the surface."""
    cos_w = np.asarray(cos_w, np.float64)
    c2 = np.maximum(cos_w * cos_w, 1e-300)
    tan2 = np.maximum(1 - c2, 0) / c2
    return np.where(cos_w > 0, 2 / (1 + np.sqrt(1 + alpha * alpha * tan2)), 0.0)


def ggx_albedo(alpha, theta_o, n=512, m=512):
    """Directional albedo  int D G1(wi) G1(wo) / (4 cos_i cos_o) cos_i dwi  for wo at theta_o.

    Integrated over half vectors h (wi = reflect(wo, h), dwi = 4 (wo.h) dh) with the
    substitution tan^2 theta_h = alpha^2 xi / (1 - xi), for which D(h) cos theta_h dh =
    dxi dphi / 2 pi:  rho = 1/2pi int G1(wi) G1(wo) (wo.h) / (cos_o cos theta_h) dxi dphi.
    Gauss-Legendre panels in xi (refined towards 1), midpoint rule in phi over [0, pi] (symmetry).
    """
    wo = np.array([math.sin(theta_o), 0.0, math.cos(theta_o)])
    edges = np.unique(np.concatenate([np.linspace(0, 0.9, 10), 1 - np.logspace(-1, -14, 14), [1.0]]))
    xi, wxi = _panels(edges, max(4, n // 8))
    phi = (np.arange(m) + 0.5) * math.pi / m
    XI, PHI = np.meshgrid(xi, phi, indexing="ij")
    den = (1 - XI) + alpha * alpha * XI         # tan^2 = alpha^2 xi / (1 - xi), without dividing by 0
    cos_h = np.sqrt((1 - XI) / den)
    sin_h = np.sqrt(alpha * alpha * XI / den)
    h = np.stack([sin_h * np.cos(PHI), sin_h * np.sin(PHI), cos_h], -1)
    oh = h @ wo
    wi_z = 2 * oh * cos_h - wo[2]
    ok = (oh > 0) & (wi_z > 0)                  # implies cos_h > 0
    val = np.where(ok, ggx_G1(wi_z, alpha) * ggx_G1(wo[2], alpha) * oh / (wo[2] * np.where(ok, cos_h, 1.0)), 0.0)
    return float((val * wxi[:, None]).sum() * (2 * math.pi / m) / (2 * math.pi))


def ggx_albedo_direct(alpha, theta_o, n=2000, m=2000):
    """The same integral on a plain midpoint grid in (cos theta_i, phi_i) (a cross-check)."""
    wo = np.array([math.sin(theta_o), 0.0, math.cos(theta_o)])
    mu = (np.arange(n) + 0.5) / n
    phi = (np.arange(m) + 0.5) * math.pi / m
    MU, PHI = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - MU * MU)
    wi = np.stack([s * np.cos(PHI), s * np.sin(PHI), MU], -1)
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    f_cos = ggx_D(h[..., 2], alpha) * ggx_G1(MU, alpha) * ggx_G1(wo[2], alpha) / (4 * wo[2])
    return float(f_cos.sum() / n * (math.pi / m) * 2)


def phong_albedo(exponent, theta_o, n=2048):
    """Directional albedo  (e+2)/2pi int max(0, wi.r)^e max(0, cos_i) dwi,  r the mirror of wo.

    In a frame around r (angle a from r, azimuth phi): wi.z = cos a cos th_r + sin a sin th_r cos phi;
    the phi integral of max(0, A + B cos phi) is done in closed form, the a integral by
    Gauss-Legendre panels split at the kink a = theta_o (where the lobe reaches the horizon).
    """
    edges = np.unique(np.concatenate([np.linspace(0, math.pi / 2, 33), [theta_o]]))
    a, wa = _panels(edges, max(8, n // 32))
    A = np.cos(a) * math.cos(theta_o)
    B = np.sin(a) * math.sin(theta_o)
    with np.errstate(divide="ignore", invalid="ignore"):
        p0 = np.arccos(np.clip(-A / np.where(B > 0, B, 1), -1, 1))
    g = np.where(A >= B, 2 * math.pi * A, np.where(A <= -B, 0.0, 2 * (A * p0 + B * np.sin(p0))))
    return float((exponent + 2) / (2 * math.pi) * np.sum(wa * np.cos(a) ** exponent * np.sin(a) * g))


def phong_albedo_direct(exponent, theta_o, n=2000, m=2000):
    r = np.array([-math.sin(theta_o), 0.0, math.cos(theta_o)])
    mu = (np.arange(n) + 0.5) / n
    phi = (np.arange(m) + 0.5) * math.pi / m
    MU, PHI = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - MU * MU)
    wi = np.stack([s * np.cos(PHI), s * np.sin(PHI), MU], -1)
    return float(((exponent + 2) / (2 * math.pi) * np.maximum(wi @ r, 0) ** exponent * MU).sum()
                 / n * (math.pi / m) * 2)


@functools.lru_cache(maxsize=None)
def directional_albedo(kind, param, theta_deg, check=True):
    th = math.radians(theta_deg)
    v = ggx_albedo(param, th) if kind == "ggx" else phong_albedo(param, th)
    if check:  # the quadrature has converged: doubling its resolution changes nothing that matters
        v2 = ggx_albedo(param, th, 1024, 1024) if kind == "ggx" else phong_albedo(param, th, 4096)
        assert abs(v - v2) < 1e-5, (kind, param, theta_deg, v, v2)
    return v


def quad_pixel_albedo(kind, param, view_deg, cam: Pinhole, normal):
    """Exact directional albedo averaged over each pixel of a narrow-fov view of a flat surface.

    The pixels' view angles stay within delta of view_deg; over that range the albedo is
    replaced by the quadratic through its values at view_deg - delta, view_deg, view_deg + delta,
    which is averaged over a 6 x 6 grid of points of each pixel (the box filter). Returns the
    (H, W) values and a bound on the interpolation error (its residual at +-delta/2, doubled).
    """
    rays = cam.pixel_samples(6)
    theta = np.degrees(np.arccos(np.clip(-(rays @ normal), -1, 1)))
    corners = np.degrees(np.arccos(np.clip(-(cam.pixel_rays(1) @ normal), -1, 1)))
    delta = max(float(np.abs(corners - view_deg).max()), float(np.abs(theta - view_deg).max())) + 1e-3
    at = view_deg + delta * np.array([-1.0, -0.5, 0.0, 0.5, 1.0])
    # the albedo is even in the view angle (isotropic BRDFs), so negative angles mirror positive ones
    val = np.array([directional_albedo(kind, param, round(abs(a), 9), check=(i == 2)) for i, a in enumerate(at)])
    coef = np.polyfit(at[[0, 2, 4]] - view_deg, val[[0, 2, 4]], 2)
    resid = float(np.abs(np.polyval(coef, at[[1, 3]] - view_deg) - val[[1, 3]]).max())
    return np.polyval(coef, theta - view_deg).mean(-1), 2 * resid + 1e-7


@pytest.mark.slow
def test_reference_quadratures():
    """The expected values themselves: closed forms and a second, independent quadrature."""
    for e in (5, 50, 300):  # energy-normalised phong at normal incidence: exactly 1
        assert abs(directional_albedo("phong", e, 0.0) - 1.0) < 1e-9
    # a very narrow phong lobe well above the horizon: cos(theta_r) (n+2)/(n+2) -> cos theta
    assert abs(phong_albedo(1e5, math.radians(45)) - math.cos(math.radians(45))) < 1e-4
    for e, th in ((5, 75), (50, 45)):
        assert abs(phong_albedo(e, math.radians(th)) - phong_albedo_direct(e, math.radians(th))) < 1e-5
    for a, th in ((0.3, 45), (0.7, 75), (0.1, 75)):
        assert abs(ggx_albedo(a, math.radians(th)) - ggx_albedo_direct(a, math.radians(th))) < 1e-4
    # a smooth conductor loses almost nothing at normal incidence, a rough one a lot
    assert 0.98 < directional_albedo("ggx", 0.1, 0.0) < 1.0
    assert directional_albedo("ggx", 0.7, 0.0) < directional_albedo("ggx", 0.3, 0.0) < 0.95


MATERIALS = [("ggx", 0.1), ("ggx", 0.3), ("ggx", 0.7), ("phong", 5.0), ("phong", 50.0), ("phong", 300.0)]
QUAD_FOV = 0.5   # degrees: every pixel sees the quad from (almost) the same direction


@pytest.fixture(scope="module")
def quad_scenes(tmp_path_factory):
    d = tmp_path_factory.mktemp("quads")
    env = "white.exr"
    cache = {}

    def get(kind, param, view_deg):
        key = (kind, param, view_deg)
        if key not in cache:
            th = math.radians(view_deg)
            mat = dict(type=kind, albedo=[0.9, 0.6, 0.3])
            mat["roughness" if kind == "ggx" else "exponent"] = param
            sub = d / f"{kind}_{param}_{view_deg}"
            sub.mkdir()
            write_env(sub, "white.exr", np.ones((4, 8, 3)))
            scene = load(sub, render=dict(width=8, height=8, spp=256, seed=11),
                         camera=dict(eye=[5 * math.sin(th), 5 * math.cos(th), 0.0], target=[0.0, 0.0, 0.0],
                                     up=[0.0, 0.0, -1.0], fov_y=QUAD_FOV),
                         environment=dict(file=env),
                         objects=[dict(shape="quad", center=[0.0, 0.0, 0.0], normal=[0.0, 1.0, 0.0], size=1.0,
                                       material="m")],
                         materials={"m": mat})
            # every ray of every pixel hits the quad (plane y = 0, |x|, |z| < 0.5)
            cam = camera_of(scene)
            rays = cam.pixel_rays(1)
            t = -cam.eye[1] / rays[..., 1]
            hit = cam.eye + t[..., None] * rays
            assert np.all(t > 0) and np.all(np.abs(hit[..., [0, 2]]) < 0.5)
            cache[key] = scene
        return cache[key]

    return get


@pytest.mark.slow
@pytest.mark.parametrize("strategy", ["bsdf", "light", "mis", "wavelet"])
@pytest.mark.parametrize("view_deg", [0.0, 45.0, 75.0])
@pytest.mark.parametrize("kind,param", MATERIALS)
def test_glossy_quad_directional_albedo(quad_scenes, kind, param, view_deg, strategy):
    """A quad under a constant environment of 1 shows albedo x (integral of f cos), seen at one angle."""
    scene = quad_scenes(kind, param, view_deg)
    spp = 1024 if strategy == "light" else 256
    r = _render(scene, strategy, spp, seed=5)
    rho, err = quad_pixel_albedo(kind, param, view_deg, camera_of(scene), np.array([0.0, 1.0, 0.0]))
    albedo = np.array([0.9, 0.6, 0.3])
    mask = np.ones((scene.height, scene.width), bool)
    # All pixels see the same BRDF from (almost) the same angle: their estimators have one law, so
    # the variance is pooled (a pixel that happened to draw none of the rare below-horizon
    # directions of a ggx lobe would otherwise claim a far too small standard error).
    # Light sampling of a narrow lobe from a uniform map is heavy-tailed (a few samples per pixel
    # land in the lobe), so it is judged on the aggregate over all pixels only.
    check_estimates(r.image, r.stderr, rho[..., None] * albedo, mask, spp, slack=err * albedo.max(),
                    exchangeable=True, per_pixel=strategy != "light",
                    label=f"{kind} {param} at {view_deg} deg/{strategy}")


# ============================================================================= 3. orientation
ORIENT_W, ORIENT_H, ORIENT_ROW, ORIENT_COL = 32, 16, 5, 20   # a texel up, left and towards +Z


def _one_texel_env(folder, w, h, row, col, radiance, name="one.exr"):
    env = np.zeros((h, w, 3), np.float32)
    env[row, col] = radiance
    return write_env(folder, name, env)


def test_lat_long_helpers_follow_the_document():
    """The test's own convention helpers against the document's statements."""
    assert np.allclose(rot_y(90) @ [1, 0, 0], [0, 0, -1])   # +90 sends the map's +X to world -Z
    d = dir_from_uv(0.3, 0.2)
    u, v = uv_from_dir(d)
    assert abs(u - 0.3) < 1e-12 and abs(v - 0.2) < 1e-12
    assert np.allclose(dir_from_uv(0.0, 0.0), [0, 1, 0])       # row 0 is the top (+Y)
    assert np.allclose(dir_from_uv(0.25, 0.5), [1, 0, 0])
    assert np.allclose(dir_from_uv(0.5, 0.5), [0, 0, 1])


@pytest.mark.parametrize("strategy", ["light", "mis"])
@pytest.mark.parametrize("rotate_y", [0.0, 90.0, 180.0, -90.0])
def test_single_texel_lights_the_predicted_side(tmp_path, rotate_y, strategy):
    """A lambert sphere lit by one texel: lit where the normal faces the texel's world direction
    (from the lat-long formula and rotate_y), exactly black where it faces away."""
    W, H, row, col = ORIENT_W, ORIENT_H, ORIENT_ROW, ORIENT_COL
    env = _one_texel_env(tmp_path, W, H, row, col, 50.0)
    # seen from above (image up = -Z), so that every rotation about +Y leaves lit and unlit
    # parts in view, on different sides of the image
    scene = load(tmp_path, render=dict(width=32, height=32, spp=64, seed=2),
                 camera=dict(eye=[0.0, 4.0, 0.0], target=[0.0, 0.0, 0.0], up=[0.0, 0.0, -1.0], fov_y=34.0),
                 environment=dict(file=env, rotate_y=rotate_y),
                 objects=[dict(shape="sphere", center=[0.0, 0.0, 0.0], radius=1.0, material="m")],
                 materials={"m": dict(type="lambert", albedo=[0.8, 0.8, 0.8])})
    light = texel_dir(row, col, W, H, rotate_y)
    margin = texel_radius(row, col, W, H) + math.radians(3)  # texel extent + facets
    cam = camera_of(scene)
    r_in = _inradius(scene, np.zeros(3))
    inner, _ = _sphere_masks(cam, np.zeros(3), r_in, 1.0)
    rays = cam.pixel_rays(4)                                  # 5 x 5 points per pixel
    t = ray_sphere(cam.eye, rays, np.zeros(3), 1.0)
    normals = cam.eye + t[..., None] * rays                   # unit sphere at the origin
    cosines = np.where(np.isfinite(t), normals @ light, np.nan)
    lit = inner & (np.where(inner[..., None], cosines, 0).min(-1) > math.sin(margin))
    dark = inner & (np.where(inner[..., None], cosines, 0).max(-1) < -math.sin(margin))
    assert lit.sum() >= 5 and dark.sum() >= 5, (lit.sum(), dark.sum())
    r = _render(scene, strategy, 64)
    lum = r.image.sum(-1)
    assert np.all(lum[dark] == 0.0), f"light on the side facing away: {np.argwhere(dark & (lum > 0))[:5]}"
    assert np.all(lum[lit] > 0.0), f"dark on the side facing the light: {np.argwhere(lit & (lum <= 0))[:5]}"


def _mirror_point(eye, centre, radius, light, iters=60):
    """Point of a mirror sphere at which the view ray from eye reflects into the distant direction light."""
    n = light + (eye - centre) / np.linalg.norm(eye - centre)
    n /= np.linalg.norm(n)
    for _ in range(iters):
        p = centre + radius * n
        v = (eye - p) / np.linalg.norm(eye - p)
        n_new = (light + v) / np.linalg.norm(light + v)
        if np.linalg.norm(n_new - n) < 1e-13:
            break
        n = n_new
    p = centre + radius * n
    v = (eye - p) / np.linalg.norm(eye - p)
    assert np.allclose(2 * (v @ n) * n - v, light, atol=1e-9)
    return p


@pytest.mark.parametrize("strategy", ["bsdf", "mis"])
@pytest.mark.parametrize("rotate_y", [0.0, 90.0])
def test_mirror_sphere_reflects_texel_at_predicted_pixel(tmp_path, rotate_y, strategy):
    W, H, row, col = ORIENT_W, ORIENT_H, ORIENT_ROW, ORIENT_COL
    env = _one_texel_env(tmp_path, W, H, row, col, 100.0)
    scene = load(tmp_path, render=dict(width=32, height=32, spp=128, seed=4),
                 camera=dict(eye=[0.0, 0.0, 4.0], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0], fov_y=40.0),
                 environment=dict(file=env, rotate_y=rotate_y),
                 objects=[dict(shape="sphere", center=[0.0, 0.0, 0.0], radius=1.0, subdivisions=6,
                               material="mirror")],
                 materials={"mirror": dict(type="ggx", albedo=[1.0, 1.0, 1.0], roughness=1e-4)})
    cam = camera_of(scene)
    # predicted image position of the texel's centre, and of a 9 x 9 grid over the texel
    centre = np.array(cam.project(_mirror_point(cam.eye, np.zeros(3), 1.0, texel_dir(row, col, W, H, rotate_y))))
    grid = np.linspace(0, 1, 9)
    pts = np.array([cam.project(_mirror_point(cam.eye, np.zeros(3), 1.0,
                                              texel_dir(row, col, W, H, rotate_y, du, dv)))
                    for du in grid for dv in grid])
    lo, hi = pts.min(0) - 1.0, pts.max(0) + 1.0              # 1 pixel for facets and rounding
    # the prediction must be off the image's centre lines so that a mirrored image would fail
    assert abs(centre[0] - 16) > 3 and abs(centre[1] - 16) > 2, centre
    r = _render(scene, strategy, 128)
    # GGX has long tails: with alpha = 1e-4, f outside ~2 degrees of the mirror direction adds
    # less than 1e-3 of the texel's radiance (light samples of mis find those tiny values).
    bright = r.image.mean(-1) > 1e-3 * 100.0
    assert bright.any(), "the texel is reflected nowhere"
    rows, cols = np.nonzero(bright)
    inside = (cols + 1 > lo[0]) & (cols < hi[0]) & (rows + 1 > lo[1]) & (rows < hi[1])
    assert inside.all(), (f"reflection at pixels (row, col) {list(zip(rows[~inside], cols[~inside]))[:6]}, "
                          f"predicted columns {lo[0]:.1f}..{hi[0]:.1f}, rows {lo[1]:.1f}..{hi[1]:.1f}")
    pr, pc = int(centre[1]), int(centre[0])
    assert bright[max(pr - 1, 0):pr + 2, max(pc - 1, 0):pc + 2].any(), (
        f"no reflection next to the predicted pixel (row {pr}, col {pc}); bright {list(zip(rows, cols))[:6]}")
    brightest = np.unravel_index(np.argmax(r.image.sum(-1)), bright.shape)
    assert abs(brightest[0] - pr) <= 1 and abs(brightest[1] - pc) <= 1, (brightest, (pr, pc))


def test_background_halves_are_not_mirrored(tmp_path):
    """Map left half (u < 1/2) is the +X hemisphere, top row the +Y one. Looking along -Z with
    up +Y, world +X is on the image's right and +Y at its top."""
    colours = np.array([[[1, 0, 0], [0, 1, 0]],      # top row: u < 1/2 red, u >= 1/2 green
                        [[0, 0, 1], [1, 1, 1]]], np.float32)  # bottom row: blue, white
    env = write_env(tmp_path, "halves.pfm", colours)
    scene = load(tmp_path, render=dict(width=16, height=8, spp=4, seed=1),
                 camera=dict(eye=[0.0, 0.0, 0.0], target=[0.0, 0.0, -1.0], up=[0.0, 1.0, 0.0], fov_y=60.0),
                 environment=dict(file=env))
    img = _render(scene, "mis", 4).image
    assert np.array_equal(img[:4, 8:], np.broadcast_to([1, 0, 0], (4, 8, 3)))  # top right: +X, +Y
    assert np.array_equal(img[:4, :8], np.broadcast_to([0, 1, 0], (4, 8, 3)))  # top left: -X, +Y
    assert np.array_equal(img[4:, 8:], np.broadcast_to([0, 0, 1], (4, 8, 3)))  # bottom right
    assert np.array_equal(img[4:, :8], np.broadcast_to([1, 1, 1], (4, 8, 3)))  # bottom left


@pytest.mark.parametrize("rotate_y", [0.0, 90.0, -30.0])
@pytest.mark.parametrize("look", ["-z", "+x", "+z", "-x", "up"])
def test_background_lookup_per_pixel(tmp_path, look, rotate_y):
    """Background pixels equal the texel the lat-long formula (after undoing rotate_y) predicts
    for every point of the pixel; pixels straddling texel borders are skipped."""
    W, H = 8, 4
    rng = np.random.default_rng(0)
    colours = rng.permutation(W * H).reshape(H, W).astype(np.float32) + 1
    pix = np.stack([colours, 100 + colours, np.full_like(colours, 7)], -1)
    env = write_env(tmp_path, "grid.exr", pix)
    fwd, up = {"-z": ([0, 0, -1], [0, 1, 0]), "+x": ([1, 0, 0], [0, 1, 0]), "+z": ([0, 0, 1], [0, 1, 0]),
               "-x": ([-1, 0, 0], [0, 1, 0]), "up": ([0, 1, 0], [0, 0, -1])}[look]
    scene = load(tmp_path, render=dict(width=32, height=24, spp=4, seed=1),
                 camera=dict(eye=[1.0, 2.0, 3.0], target=list(np.add([1.0, 2.0, 3.0], fwd)), up=up, fov_y=80.0),
                 environment=dict(file=env, rotate_y=rotate_y))
    cam = camera_of(scene)
    d_map = cam.pixel_rays(4) @ rot_y(rotate_y)   # world = R map  ->  map = R^T world
    u, v = uv_from_dir(d_map)
    texel = np.minimum((v * H).astype(int), H - 1) * W + np.minimum((u * W).astype(int), W - 1)
    same = np.all(texel == texel[..., :1], -1)
    assert same.mean() > 0.6 and len(np.unique(texel[same][:, 0])) >= 3
    expected = pix.reshape(-1, 3)[texel[..., 0]]
    img = _render(scene, "bsdf", 4).image
    wrong = same & np.any(img != expected, -1)
    assert not wrong.any(), (f"{wrong.sum()} pixels show another texel, e.g. at {np.argwhere(wrong)[:3].tolist()}: "
                             f"{img[wrong][:3].tolist()} instead of {expected[wrong][:3].tolist()}")


# ============================================================================= 4. visibility
def _texel_cos_integral(row, H, W):
    """Integral of cos(theta) (theta from +Y) over a lat-long texel in row `row` (all above the horizon)."""
    th0, th1 = row * math.pi / H, (row + 1) * math.pi / H
    assert th1 <= math.pi / 2
    return (2 * math.pi / W) * (math.sin(th1) ** 2 - math.sin(th0) ** 2) / 2


def test_far_geometry_does_not_move_shadows(tmp_path):
    """Shadow rays start a distance from the hit point set by the hit point, its face and the
    eye, not by the whole scene: a 1 cm quad 3000 units away (it blocks no light that
    matters) leaves the image of a sphere on a floor unchanged. With an offset relative to
    the scene's size it moved from 6e-4 to 0.3 and the contact shadow brightened."""
    sky = write_env(tmp_path, "sky.exr", wavlight.envmap.procedural_sky(width=64, height=32, sun_radiance=300.0))
    objects = [dict(shape="quad", center=[0.0, 0.0, 0.0], normal=[0.0, 1.0, 0.0], size=6.0, material="m"),
               dict(shape="sphere", center=[0.0, 0.5, 0.0], radius=0.5, subdivisions=3, material="m")]
    far = dict(shape="quad", center=[0.0, 1.0, 3000.0], normal=[0.0, 0.0, -1.0], size=0.01, material="m")
    common = dict(render=dict(width=24, height=24, spp=8, seed=3),
                  camera=dict(eye=[0.0, 1.5, -3.0], target=[0.0, 0.3, 0.0], up=[0.0, 1.0, 0.0], fov_y=40.0),
                  environment=dict(file=sky), materials={"m": dict(type="lambert", albedo=[0.7, 0.7, 0.7])})
    near = _render(load(tmp_path, objects=objects, **common), "mis", 8).image
    with_far = _render(load(tmp_path, objects=objects + [far], **common), "mis", 8).image
    assert near.max() > 0
    np.testing.assert_allclose(with_far, near, rtol=0, atol=1e-5 * near.max())


@pytest.mark.parametrize("eye_distance", [10.0, 7000.0])
def test_no_self_shadowing_near_the_origin_seen_from_afar(tmp_path, eye_distance):
    """A tilted quad through the origin under a constant sky of 1, lambert albedo 0.5,
    cosine sampling: every estimate is exactly 0.5 unless its shadow ray hits the quad it
    left. Near the origin 1e-4 |p| is tiny, so the offset floors of the face and of the
    eye (RayTracer.shadow_offsets; float32 rounding of eye + t d grows with |eye|) must hold
    the ray off the surface. Without them (kernel offset 1e-4 |p| alone) most pixels of
    the far view showed acne."""
    sky = write_env(tmp_path, "white.exr", np.ones((4, 8, 3)))
    normal = np.array([1.0, 2.0, 3.0]) / np.linalg.norm([1.0, 2.0, 3.0])
    eye = normal * eye_distance + np.array([0.3, -0.2, 0.1]) * eye_distance * 0.3
    fov = math.degrees(2 * math.atan(0.5 / np.linalg.norm(eye)))
    scene = load(tmp_path, render=dict(width=16, height=16, spp=8, seed=3),
                 camera=dict(eye=eye.tolist(), target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0], fov_y=fov),
                 environment=dict(file=sky),
                 objects=[dict(shape="quad", center=[0.0, 0.0, 0.0], normal=normal.tolist(), size=4.0,
                               material="m")],
                 materials={"m": dict(type="lambert", albedo=[0.5, 0.5, 0.5])})
    img = _render(scene, "cosine", 8).image
    np.testing.assert_allclose(img, 0.5, rtol=1e-5)


SHADOW_W, SHADOW_H, SHADOW_ROW, SHADOW_COL = 64, 32, 6, 40   # elevation ~53 deg


@pytest.mark.parametrize("strategy", ["light", "mis"])
@pytest.mark.parametrize("rotate_y", [0.0, 90.0])
def test_occluder_casts_shadow_at_predicted_place(tmp_path, rotate_y, strategy):
    """Floor (lambert, y = 0) lit by one bright texel, a sphere between them: floor points whose
    every ray to the texel hits the sphere are exactly black; points none of whose rays come
    near it receive albedo/pi x radiance x (integral of cos over the texel)."""
    W, H, row, col = SHADOW_W, SHADOW_H, SHADOW_ROW, SHADOW_COL
    radiance, albedo = 200.0, 0.6
    env = _one_texel_env(tmp_path, W, H, row, col, radiance)
    light = texel_dir(row, col, W, H, rotate_y)
    occ_c, occ_r = np.array([0.0, 1.2, 0.0]), 0.6
    shadow = occ_c - occ_c[1] / light[1] * light            # where the shadow's centre falls
    away = np.array([-light[0], light[1], -light[2]])        # view from the other side of the light
    eye = shadow + 7 * away / np.linalg.norm(away)
    scene = load(tmp_path, render=dict(width=32, height=32, spp=128, seed=9),
                 camera=dict(eye=eye.tolist(), target=shadow.tolist(), up=[0.0, 1.0, 0.0], fov_y=30.0),
                 environment=dict(file=env, rotate_y=rotate_y),
                 objects=[dict(shape="quad", center=[0.0, 0.0, 0.0], normal=[0.0, 1.0, 0.0], size=12.0,
                               material="floor"),
                          dict(shape="sphere", center=occ_c.tolist(), radius=occ_r, subdivisions=4,
                               material="occluder")],
                 materials={"floor": dict(type="lambert", albedo=[albedo] * 3),
                            "occluder": dict(type="lambert", albedo=[0.5, 0.5, 0.5])})
    cam = camera_of(scene)
    occ_faces = scene.face_material[:] == [m.name for m in scene.materials].index("occluder")
    v = scene.vertices.astype(np.float64)
    f = scene.faces[occ_faces]
    nrm = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    r_in = float(np.abs(np.einsum("ij,ij->i", nrm, v[f[:, 0]] - occ_c)).min())

    # floor points of each pixel: centre and corners
    corners = cam.pixel_rays(1)
    centre_rays = cam.centre_rays()
    t_c = -cam.eye[1] / centre_rays[..., 1]
    p = cam.eye + t_c[..., None] * centre_rays
    t_k = -cam.eye[1] / corners[..., 1]
    pk = cam.eye + t_k[..., None] * corners
    foot = np.linalg.norm(pk - p[..., None, :], axis=-1).max(-1)
    # pixels whose camera rays may touch the occluder are not floor pixels
    _, off_occluder = _sphere_masks(cam, occ_c, r_in, occ_r)
    floor_px = np.all(t_k > 0, -1) & off_occluder & np.all(np.abs(pk[..., [0, 2]]) < 5.9, axis=(-1, -2))
    # distance of the central shadow ray to the occluder's centre, with a Lipschitz margin covering
    # the pixel footprint and the texel's angular radius
    dist = line_distance(p, light, occ_c)
    reach = np.linalg.norm(occ_c - p, axis=-1) + foot
    margin = foot + reach * texel_radius(row, col, W, H) + 1e-3
    umbra = floor_px & (dist < r_in - margin)
    lit = floor_px & (dist > occ_r + margin)
    assert umbra.sum() >= 30 and lit.sum() >= 200, (umbra.sum(), lit.sum())

    spp = 128
    r = _render(scene, strategy, spp)
    assert np.all(r.image[umbra] == 0.0), f"light inside the umbra: {r.image[umbra].max(0)}"
    expected = albedo / math.pi * radiance * _texel_cos_integral(row, H, W)
    # a flat floor under a distant light: every lit pixel's estimator has the same law
    check_estimates(r.image, r.stderr, expected, lit, spp, exchangeable=True, label=f"lit floor/{strategy}")


@pytest.mark.parametrize("strategy", ["light", "mis"])
@pytest.mark.parametrize("texel", [(64, 32, 6, 40), (32, 16, 3, 9), (16, 8, 2, 3)])
def test_single_texel_floor_is_lit_correctly(tmp_path, texel, strategy):
    """An unoccluded lambert floor under one bright texel: albedo/pi x radiance x integral of cos
    over the texel, computed in closed form. Isolates light sampling of a small bright texel."""
    W, H, row, col = texel
    radiance, albedo = 200.0, 0.6
    env = _one_texel_env(tmp_path, W, H, row, col, radiance)
    scene = load(tmp_path, render=dict(width=16, height=16, spp=256, seed=13),
                 camera=dict(eye=[0.0, 6.0, 0.0], target=[0.0, 0.0, 0.0], up=[0.0, 0.0, -1.0], fov_y=40.0),
                 environment=dict(file=env),
                 objects=[dict(shape="quad", center=[0.0, 0.0, 0.0], normal=[0.0, 1.0, 0.0], size=8.0,
                               material="floor")],
                 materials={"floor": dict(type="lambert", albedo=[albedo] * 3)})
    spp = 256
    r = _render(scene, strategy, spp)
    expected = albedo / math.pi * radiance * _texel_cos_integral(row, H, W)
    check_estimates(r.image, r.stderr, expected, np.ones((16, 16), bool), spp, exchangeable=True,
                    label=f"floor under texel {texel}/{strategy}")


QUADS = {
    "origin": dict(center=[0.0, 0.0, 0.0], normal=[0.0, 1.0, 0.0], size=2.0, view=1.0),
    "far_tilted": dict(center=[40.0, -25.0, 60.0], normal=[0.3, 0.8, -0.5], size=[30.0, 20.0], view=1.0),
    "far_tilted_back": dict(center=[40.0, -25.0, 60.0], normal=[0.3, 0.8, -0.5], size=[30.0, 20.0], view=-1.0),
    "very_far": dict(center=[2000.0, 500.0, -3000.0], normal=[-0.6, 0.2, 0.77], size=300.0, view=1.0),
}


@pytest.mark.parametrize("strategy", ALL_STRATEGIES)
@pytest.mark.parametrize("case", list(QUADS))
def test_flat_quad_under_uniform_sky_is_uniform(tmp_path, case, strategy):
    """No self-shadowing: a lambert quad under a constant environment of 1 is exactly albedo
    everywhere, wherever it is, however it is tilted, from either side."""
    q = QUADS[case]
    env = write_env(tmp_path, "white.exr", np.ones((4, 8, 3)))
    c = np.array(q["center"])
    n = np.array(q["normal"]) / np.linalg.norm(q["normal"])
    size = np.broadcast_to(np.asarray(q["size"], float), (2,))
    side = np.cross(n, [0.0, 1.0, 0.0]) if abs(n[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    view = q["view"] * (n + 0.6 * side)
    eye = c + 0.8 * size.min() * view / np.linalg.norm(view)
    albedo = [0.55, 0.35, 0.8]
    scene = load(tmp_path, render=dict(width=16, height=16, spp=64, seed=21),
                 camera=dict(eye=eye.tolist(), target=c.tolist(), up=[0.0, 1.0, 0.0], fov_y=25.0),
                 environment=dict(file=env),
                 objects=[dict(shape="quad", center=q["center"], normal=q["normal"], size=q["size"],
                               material="m")],
                 materials={"m": dict(type="lambert", albedo=albedo)})
    cam = camera_of(scene)
    rays = cam.pixel_rays(1)
    t = ((c - cam.eye) @ n) / (rays @ n)
    hit = cam.eye + t[..., None] * rays - c
    t1 = np.cross([0.0, 1.0, 0.0], n)   # the document's quad axes: normalize(Y x n), or +X
    t1 = t1 / np.linalg.norm(t1) if np.linalg.norm(t1) > 1e-9 else np.array([1.0, 0.0, 0.0])
    t2 = np.cross(n, t1)
    assert np.all(t > 0) and np.all(np.abs(hit @ t1) < size[0] / 2) and np.all(np.abs(hit @ t2) < size[1] / 2)
    spp = 64
    r = _render(scene, strategy, spp)
    mask = np.ones((16, 16), bool)
    if strategy in ("cosine", "bsdf"):
        assert np.all(r.stderr < 1e-6)
    check_estimates(r.image, r.stderr, albedo, mask, spp, label=f"quad {case}/{strategy}")


# ============================================================================= 5. determinism
@pytest.fixture(scope="module")
def busy_scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("busy")
    rng = np.random.default_rng(5)
    env = rng.gamma(0.5, 1.0, (32, 64, 3)).astype(np.float32)
    env[6, 20] = 500.0
    name = write_env(d, "busy.exr", env)
    return load(d, render=dict(width=80, height=56, spp=24, seed=17),
                camera=dict(eye=[0.5, 1.5, 4.0], target=[0.0, 0.3, 0.0], up=[0.0, 1.0, 0.0], fov_y=45.0),
                environment=dict(file=name, rotate_y=25.0),
                objects=[dict(shape="quad", center=[0.0, 0.0, 0.0], normal=[0.0, 1.0, 0.0], size=6.0,
                              material="floor"),
                         dict(shape="sphere", center=[-0.6, 0.6, 0.0], radius=0.6, subdivisions=3,
                              material="gold"),
                         dict(shape="sphere", center=[0.8, 0.5, 0.3], radius=0.5, subdivisions=3,
                              material="plastic")],
                materials={"floor": dict(type="lambert", albedo=[0.6, 0.6, 0.6]),
                           "gold": dict(type="ggx", albedo=[1.0, 0.78, 0.34], roughness=0.2),
                           "plastic": dict(type="phong", albedo=[0.5, 0.7, 0.9], exponent=40.0)})


@pytest.mark.slow
@pytest.mark.parametrize("strategy", ALL_STRATEGIES)
def test_same_seed_same_image_any_thread_count(busy_scene, strategy):
    a = wavlight.render_full(busy_scene, strategy=strategy, threads=1)
    assert a.stats["tiles"] > 1   # several tiles, so threads really interleave
    b = wavlight.render_full(busy_scene, strategy=strategy, threads=2)
    c = wavlight.render_full(busy_scene, strategy=strategy, threads=2)
    assert np.all(np.isfinite(a.image)) and a.image.max() > 0
    assert np.array_equal(a.image, b.image) and np.array_equal(a.stderr, b.stderr)
    assert np.array_equal(b.image, c.image) and np.array_equal(b.stderr, c.stderr)
    assert np.array_equal(wavlight.render(busy_scene, strategy=strategy, threads=2), a.image)


@pytest.mark.parametrize("sampler", ["independent", "stratified"])
def test_small_image_with_many_spp_is_cut_into_parts(busy_scene, sampler):
    """One 8 x 8 tile of 4096 spp holds four passes: it renders as four parts (the progress
    bar moves, both threads work), the image does not depend on the thread count, and with
    independent samples it equals the tile rendered in one piece (Philox numbers are indexed
    by sample, so the cut changes only the order of float64 sums)."""
    from wavlight import integrator

    events = []
    kw = dict(strategy="mis", spp=4096, width=8, height=8, sampler=sampler)
    a = wavlight.render_full(busy_scene, threads=1, progress=lambda *e: events.append(e), **kw)
    b = wavlight.render_full(busy_scene, threads=2, **kw)
    assert a.stats["tiles"] == 1 and [e[:2] for e in events] == [(1, 4), (2, 4), (3, 4), (4, 4)]
    assert events[-1][2] == 8 * 8 * 4096
    assert np.array_equal(a.image, b.image) and np.array_equal(a.stderr, b.stderr)
    if sampler == "independent":
        r = integrator._Renderer(busy_scene, "mis", 4096, 8, 8, busy_scene.seed, 1)
        whole, err = r.tile(0, 0, 0, 8, 8)
        np.testing.assert_allclose(a.image, whole, rtol=1e-6, atol=1e-7)


def _edited(scene, **changes):
    import copy
    import dataclasses

    return dataclasses.replace(copy.copy(scene), **changes)


@pytest.mark.parametrize("edit, message", [
    (lambda s: _edited(s, face_material=s.face_material[:-3]), "face_material"),
    (lambda s: _edited(s, face_material=s.face_material + 7), "face_material out of range"),
    (lambda s: _edited(s, faces=s.faces + len(s.vertices)), "face indices out of range"),
    (lambda s: _edited(s, spp=0), "spp"),
    (lambda s: _edited(s, width=0), "width"),
    (lambda s: _edited(s, seed=-1), "seed"),
    (lambda s: _edited(s, options={"light_levels": 50}), "light_levels"),
    (lambda s: _edited(s, options=None), "options must be a dict"),
    (lambda s: _edited(s, environment=None), "environment"),
    (lambda s: _edited(s, camera=wavlight.scene.Camera(s.camera.eye, s.camera.eye, s.camera.up, 40.0)), "eye"),
    (lambda s: _edited(s, camera=wavlight.scene.Camera(s.camera.eye, s.camera.target, s.camera.up, 200.0)), "fov"),
    (lambda s: _edited(s, materials=[]), "face_material out of range"),
    (lambda s: _edited(s, materials=[wavlight.scene.Material("g", 2, np.ones(3, np.float32), 0.0)] * 3),
     "parameter"),
    (lambda s: "no such scene", "no such file"),
    (lambda s: None, "expected a Scene"),
])
def test_render_full_checks_the_scene_itself(busy_scene, edit, message):
    """A Scene built or edited in Python skips load_scene's checks: render_full checks what the
    kernels rely on (a face_material shorter than the faces once crashed the interpreter)."""
    with pytest.raises(wavlight.WavlightError, match=message):
        wavlight.render_full(edit(busy_scene))


def test_render_takes_a_path_and_render_full_options(tmp_path, busy_scene):
    path = tmp_path / "s.toml"
    path.write_text('[render]\nwidth = 8\nheight = 6\nspp = 2\n[camera]\neye = [0, 1, 4]\ntarget = [0, 0, 0]\n'
                    '[environment]\nprocedural = "sky"\n')
    a = wavlight.render(str(path), sampler="stratified")
    b = wavlight.render(wavlight.load_scene(str(path)), sampler="stratified")
    assert a.shape == (6, 8, 3) and np.array_equal(a, b)


def test_submodules_are_attributes_of_the_package():
    assert callable(wavlight.evaluation.experiment.run_experiment) and callable(wavlight.evaluation.stability.run_stability)
    with pytest.raises(AttributeError):
        wavlight.no_such_module


def test_different_seeds_differ(busy_scene):
    a = wavlight.render(busy_scene, strategy="mis", seed=1)
    b = wavlight.render(busy_scene, strategy="mis", seed=2)
    assert not np.array_equal(a, b)
    # ...but only by noise: the two estimates agree within their standard errors on average
    ra = wavlight.render_full(busy_scene, strategy="mis", seed=1)
    rb = wavlight.render_full(busy_scene, strategy="mis", seed=2)
    d = (ra.image.astype(np.float64) - rb.image).mean((0, 1))
    se = np.sqrt((ra.stderr.astype(np.float64) ** 2 + rb.stderr.astype(np.float64) ** 2).sum((0, 1))) / ra.image[..., 0].size
    assert np.all(np.abs(d) < 4.5 * se + 1e-6), (d, se)
