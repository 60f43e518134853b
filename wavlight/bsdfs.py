"""The four BRDFs of the scene format: evaluation, sampling and pdf (numpy, local frame).

All functions work on batches in the local shading frame (normal = +z). ``wo`` is
the direction towards the viewer (``wo.z > 0`` after two-sided flipping). ``eval``
returns f(wi, wo) * max(0, cos theta_i), the cosine-weighted BRDF without albedo
colour (a scalar per sample; the albedo multiplies outside). ``plastic`` is the one
whose albedo does not factor out: :func:`plastic_parts` gives its two scalars, the
specular part (no albedo) and the diffuse part (times the albedo), whose sum is its
``eval``, and :func:`tint` the colour that turns that sum into f cos with albedo.
Plastic needs its table (:func:`plastic_table`, one row per sample). Every ``sample``
returns directions and the exact pdf per unit solid angle that ``pdf`` gives for
the same directions.

| type    | f                                                  | sampling                          |
|---------|----------------------------------------------------|-----------------------------------|
| lambert | albedo / pi                                        | cosine hemisphere                 |
| phong   | albedo (n+2)/(2 pi) max(0, wi.r)^n, r mirror of wo | cos^n lobe about r, (n+1)/(2 pi)  |
| ggx     | albedo D G1(wi) G1(wo) / (4 cos_i cos_o)           | visible normals (Heitz 2018)      |
| plastic | F D G1 G1 / (4 cos_i cos_o) + albedo T T / (pi eta^2 (1 - R_int)) | a lobe chosen, then ggx's or the cosine |

plastic is Mitsuba 3's ``roughplastic`` (GGX, ``nonlinear`` false, ``ext_ior`` 1, specular
reflectance 1): docs/decisions/plastic-material.md gives the formula and its source.
"""
from __future__ import annotations

import functools

import numpy as np

from . import warp

LAMBERT, PHONG, GGX, PLASTIC = 0, 1, 2, 3
TYPES = {"lambert": LAMBERT, "phong": PHONG, "ggx": GGX, "plastic": PLASTIC}


def reflect(wo):
    return np.stack([-wo[:, 0], -wo[:, 1], wo[:, 2]], 1)


# ----------------------------------------------------------------------------- lambert
def lambert_eval(wi):
    return np.maximum(wi[:, 2], 0.0) * warp.INV_PI


# ----------------------------------------------------------------------------- phong
def _phong_cos_alpha(wi, wo):
    return np.einsum("ij,ij->i", wi, reflect(wo))


def _phong_lobe(wi, wo, exponent):
    """cos^n(alpha) where cos(alpha) > 0, else 0 (also for n = 0, where 0 ** 0 would be 1:
    the sampler never leaves the hemisphere about the mirror direction; as kernels/bsdf.h)."""
    ca = _phong_cos_alpha(wi, wo)
    return np.where(ca > 0.0, np.maximum(ca, 0.0) ** exponent, 0.0)


def phong_eval(wi, wo, exponent):
    return (exponent + 2.0) * warp.INV_2PI * _phong_lobe(wi, wo, exponent) * np.maximum(wi[:, 2], 0.0)


def phong_pdf(wi, wo, exponent):
    return (exponent + 1.0) * warp.INV_2PI * _phong_lobe(wi, wo, exponent)


def phong_sample(u, wo, exponent):
    """Directions with density (n+1)/(2 pi) cos^n(alpha) about the mirror direction."""
    cos_a = u[:, 0] ** (1.0 / (exponent + 1.0))
    sin_a = np.sqrt(np.maximum(0.0, 1.0 - cos_a * cos_a))
    phi = 2.0 * np.pi * u[:, 1]
    lobe = np.stack([sin_a * np.cos(phi), sin_a * np.sin(phi), cos_a], 1)
    r = reflect(wo)
    s, t = warp.frame(r)
    wi = warp.to_world(lobe, s, t, r)
    return wi, phong_pdf(wi, wo, exponent)


# ----------------------------------------------------------------------------- ggx
def ggx_d(h, alpha):
    c2 = h[:, 2] ** 2
    a2 = alpha * alpha
    d = np.pi * (c2 * (a2 - 1.0) + 1.0) ** 2
    return np.where(h[:, 2] > 0, a2 / d, 0.0)


def ggx_g1(w, alpha):
    c2 = np.maximum(w[:, 2] ** 2, 1e-30)
    tan2 = np.maximum(1.0 - c2, 0.0) / c2
    return np.where(w[:, 2] > 0, 2.0 / (1.0 + np.sqrt(1.0 + alpha * alpha * tan2)), 0.0)


def _half(wi, wo):
    h = wi + wo
    n = np.linalg.norm(h, axis=1, keepdims=True)
    return np.where(n > 0, h / np.where(n > 0, n, 1.0), np.array([0.0, 0.0, 1.0]))


def ggx_eval(wi, wo, alpha):
    h = _half(wi, wo)
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0) & (np.einsum("ij,ij->i", wi, h) > 0)
    cos_o = np.maximum(wo[:, 2], 1e-12)
    val = ggx_d(h, alpha) * ggx_g1(wi, alpha) * ggx_g1(wo, alpha) / (4.0 * cos_o)
    return np.where(ok, val, 0.0)


def ggx_pdf(wi, wo, alpha):
    """Visible-normal density reflected: G1(wo) D(h) / (4 cos_o)."""
    h = _half(wi, wo)
    ok = (wo[:, 2] > 0) & (np.einsum("ij,ij->i", wi, h) > 0) & (np.einsum("ij,ij->i", wo, h) > 0)
    cos_o = np.maximum(wo[:, 2], 1e-12)
    return np.where(ok, ggx_g1(wo, alpha) * ggx_d(h, alpha) / (4.0 * cos_o), 0.0)


def ggx_sample(u, wo, alpha):
    """Heitz 2018, "Sampling the GGX distribution of visible normals"."""
    vh = np.stack([alpha * wo[:, 0], alpha * wo[:, 1], wo[:, 2]], 1)
    vh /= np.linalg.norm(vh, axis=1, keepdims=True)
    lensq = vh[:, 0] ** 2 + vh[:, 1] ** 2
    safe = lensq > 0
    inv = np.where(safe, 1.0 / np.sqrt(np.where(safe, lensq, 1.0)), 0.0)
    t1 = np.where(safe[:, None], np.stack([-vh[:, 1] * inv, vh[:, 0] * inv, np.zeros_like(inv)], 1),
                  np.array([1.0, 0.0, 0.0]))
    t2 = np.cross(vh, t1)
    r = np.sqrt(u[:, 0])
    phi = 2.0 * np.pi * u[:, 1]
    p1 = r * np.cos(phi)
    p2 = r * np.sin(phi)
    s = 0.5 * (1.0 + vh[:, 2])
    p2 = (1.0 - s) * np.sqrt(np.maximum(0.0, 1.0 - p1 * p1)) + s * p2
    p3 = np.sqrt(np.maximum(0.0, 1.0 - p1 * p1 - p2 * p2))
    nh = p1[:, None] * t1 + p2[:, None] * t2 + p3[:, None] * vh
    h = np.stack([alpha * nh[:, 0], alpha * nh[:, 1], np.maximum(1e-7, nh[:, 2])], 1)
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    wi = 2.0 * np.einsum("ij,ij->i", wo, h)[:, None] * h - wo
    return wi, ggx_pdf(wi, wo, alpha)


# ----------------------------------------------------------------------------- plastic
# Mitsuba 3's roughplastic (src/bsdfs/roughplastic.cpp) with GGX, nonlinear = false,
# ext_ior = 1 and specular reflectance 1; docs/decisions/plastic-material.md.
PLASTIC_RES = 64        # MI_ROUGH_TRANSMITTANCE_RES: the transmittance table's entries over cos in [0, 1]
PLASTIC_HEAD = 4        # eta, specular sampling weight, diffuse scale, alpha
PLASTIC_STRIDE = PLASTIC_HEAD + PLASTIC_RES   # floats per material in the kernels' table (kernels/bsdf.h)
MIN_ALPHA = 1e-4        # Mitsuba's MicrofacetDistribution clamps alpha from below


def fresnel_dielectric(cos_i, eta):
    """Unpolarized Fresnel reflectance of a dielectric interface of relative index eta for
    incident cosines cos_i (either side), and cos_t, eta_ti as Mitsuba's ``fresnel``
    (include/mitsuba/render/fresnel.h) returns them: r, signed cos_t, eta_ti."""
    cos_i = np.asarray(cos_i, np.float64)
    outside = cos_i >= 0
    eta_it = np.where(outside, eta, 1.0 / eta)
    eta_ti = np.where(outside, 1.0 / eta, eta)
    cos_t2 = 1.0 - (1.0 - cos_i * cos_i) * eta_ti * eta_ti
    ci = np.abs(cos_i)
    ct = np.sqrt(np.maximum(cos_t2, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        a_s = (ci - eta_it * ct) / (ci + eta_it * ct)
        a_p = (ct - eta_it * ci) / (ct + eta_it * ci)
    r = 0.5 * (a_s * a_s + a_p * a_p)
    r = np.where(ci == 0.0, 1.0, r)
    return r, np.where(outside, -ct, ct), eta_ti


def _mitsuba_visible_normals(wi, alpha, u):
    """Mitsuba 3's GGX visible-normal sampling (include/mitsuba/render/microfacet.h, ``sample``
    with ``sample_visible``, isotropic): the warp its reflectance tables integrate with."""
    wp = np.stack([alpha * wi[:, 0], alpha * wi[:, 1], wi[:, 2]], 1)
    wp /= np.linalg.norm(wp, axis=1, keepdims=True)
    sin2 = 1.0 - wp[:, 2] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        cs = np.clip(wp[:, :2] / np.sqrt(sin2)[:, None], -1.0, 1.0)
    tiny = np.abs(sin2) <= 4.0 * np.finfo(np.float32).eps
    cos_phi, sin_phi = np.where(tiny, 1.0, cs[:, 0]), np.where(tiny, 0.0, cs[:, 1])
    cos_t = wp[:, 2]
    x, y = 2.0 * u[:, 0] - 1.0, 2.0 * u[:, 1] - 1.0   # concentric disk (Shirley & Chiu, Cline's form)
    q13 = np.abs(x) < np.abs(y)
    r, rp = np.where(q13, y, x), np.where(q13, x, y)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = 0.25 * np.pi * rp / r
    phi = np.where(q13, 0.5 * np.pi - phi, phi)
    phi = np.where((x == 0) & (y == 0), 0.0, phi)
    px, py = r * np.cos(phi), r * np.sin(phi)
    s = 0.5 * (1.0 + cos_t)
    py = (1.0 - s) * np.sqrt(np.maximum(1.0 - px * px, 0.0)) + s * py
    pz = np.sqrt(np.maximum(1.0 - px * px - py * py, 0.0))
    sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
    norm = 1.0 / (sin_t * py + cos_t * pz)
    sx, sy = (cos_t * py - sin_t * pz) * norm, px * norm
    sx, sy = (cos_phi * sx - sin_phi * sy) * alpha, (sin_phi * sx + cos_phi * sy) * alpha
    m = np.stack([-sx, -sy, np.ones_like(sx)], 1)
    return m / np.linalg.norm(m, axis=1, keepdims=True)


def _smith_g1(v, m, alpha):
    """Mitsuba's GGX smith_g1(v, m): 0 where v sees the back of m."""
    xy2 = alpha * alpha * (v[:, 0] ** 2 + v[:, 1] ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = 2.0 / (1.0 + np.sqrt(1.0 + xy2 / v[:, 2] ** 2))
    g = np.where(xy2 == 0.0, 1.0, g)
    return np.where(np.einsum("ij,ij->i", v, m) * v[:, 2] <= 0.0, 0.0, g)


def _rough_dielectric(alpha, eta, reflect, res):
    """Mitsuba's eval_reflectance (reflect) or eval_transmittance of a rough dielectric
    interface, at the PLASTIC_RES cosines mu = max(1e-6, linspace(0, 1)): res x res
    Gauss-Legendre nodes over the visible-normal warp's square."""
    mu = np.maximum(1e-6, np.linspace(0.0, 1.0, PLASTIC_RES))
    nodes, weights = np.polynomial.legendre.leggauss(res)
    ux, uy = np.meshgrid(nodes, nodes)
    wx, wy = np.meshgrid(weights, weights)
    u = np.stack([ux.ravel(), uy.ravel()], 1) * 0.5 + 0.5
    w = (wx * wy).ravel() * 0.25
    out = np.zeros(PLASTIC_RES)
    for i, c in enumerate(mu):   # the table's 64 cosines, each a vectorized quadrature
        wi = np.tile([np.sqrt(1.0 - c * c), 0.0, c], (len(u), 1))
        m = _mitsuba_visible_normals(wi, alpha, u)
        dot = np.einsum("ij,ij->i", wi, m)
        f, cos_t, eta_ti = fresnel_dielectric(dot, eta)
        if reflect:
            wo = 2.0 * dot[:, None] * m - wi
            g = _smith_g1(wo, m, alpha) * f
            g = np.where((wo[:, 2] <= 0) | (wi[:, 2] <= 0), 0.0, g)
        else:
            wo = m * (dot * eta_ti + cos_t)[:, None] - wi * eta_ti[:, None]
            g = _smith_g1(wo, m, alpha) * (1.0 - f)
            g = np.where(wo[:, 2] * wi[:, 2] >= 0, 0.0, g)
        out[i] = np.sum(g * w)
    return mu, out


@functools.lru_cache(maxsize=64)
def _plastic_tables(alpha: float, eta: float):
    """(external transmittance (PLASTIC_RES,), internal reflectance) as roughplastic's
    parameters_changed computes them: T(mu) of the rough interface from outside, and
    R_int = 2 mean(mu R(mu)) of the interface seen from inside (relative index 1 / eta)."""
    res_out = 32 if eta > 1 else 128
    res_in = 32 if 1.0 / eta > 1 else 128
    _, t = _rough_dielectric(alpha, eta, False, res_out)
    mu, r = _rough_dielectric(alpha, 1.0 / eta, True, res_in)
    return t, float(np.mean(r * mu) * 2.0)


def plastic_table(alpha: float, ior: float, albedo) -> np.ndarray:
    """A plastic material's row of the kernels' table (PLASTIC_STRIDE float32): eta = ior,
    the specular sampling weight 1 / (mean(albedo) + 1), the diffuse scale 1 / (pi eta^2 (1 -
    R_int)), alpha (at least MIN_ALPHA), then the transmittance T at PLASTIC_RES cosines."""
    alpha = max(float(alpha), MIN_ALPHA)
    t, r_int = _plastic_tables(alpha, float(ior))
    row = np.zeros(PLASTIC_STRIDE, np.float32)
    row[0] = ior
    row[1] = 1.0 / (float(np.mean(albedo)) + 1.0)
    row[2] = 1.0 / (np.pi * ior * ior * (1.0 - r_int))
    row[3] = alpha
    row[PLASTIC_HEAD:] = t
    return row


def transmittance(table, cos):
    """T(cos) by Mitsuba's lerp_gather: linear between the table's entries (cos in [0, 1])."""
    table = np.asarray(table, np.float64)
    x = np.asarray(cos, np.float64) * (PLASTIC_RES - 1)
    idx = np.clip(np.floor(x), 0, PLASTIC_RES - 2).astype(np.int64)
    rows = np.arange(len(table))
    v0 = table[rows, PLASTIC_HEAD + idx]
    v1 = table[rows, PLASTIC_HEAD + idx + 1]
    return v0 + (v1 - v0) * (x - idx)


def plastic_spec_prob(wo, table):
    """The probability of sampling the specular lobe: (1 - T(cos_o)) w / ((1 - T(cos_o)) w +
    T(cos_o) (1 - w)), w the table's specular sampling weight (roughplastic's sample)."""
    table = np.asarray(table, np.float64)
    t = transmittance(table, np.clip(wo[:, 2], 0.0, 1.0))
    w = table[:, 1]
    ps, pd = (1.0 - t) * w, t * (1.0 - w)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ps + pd > 0, ps / (ps + pd), 0.0)


def plastic_parts(wi, wo, table):
    """(specular, diffuse) f cos of plastic, neither with the albedo: F(wo.h) ggx, and
    T(cos_o) T(cos_i) cos_i / (pi eta^2 (1 - R_int)), the part the albedo multiplies."""
    table = np.asarray(table, np.float64)
    alpha, eta = table[:, 3], table[:, 0]
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    h = _half(wi, wo)
    f = fresnel_dielectric(np.einsum("ij,ij->i", wo, h), eta)[0]
    spec = f * ggx_eval(wi, wo, alpha)
    ci, co = np.clip(wi[:, 2], 0.0, 1.0), np.clip(wo[:, 2], 0.0, 1.0)
    diff = table[:, 2] * ci * transmittance(table, ci) * transmittance(table, co)
    return np.where(ok, spec, 0.0), np.where(ok, diff, 0.0)


def plastic_eval(wi, wo, table):
    spec, diff = plastic_parts(wi, wo, table)
    return spec + diff


def plastic_pdf(wi, wo, table):
    table = np.asarray(table, np.float64)
    q = plastic_spec_prob(wo, table)
    p = q * ggx_pdf(wi, wo, table[:, 3]) + (1.0 - q) * np.maximum(wi[:, 2], 0.0) * warp.INV_PI
    return np.where((wi[:, 2] > 0) & (wo[:, 2] > 0), p, 0.0)


def plastic_sample(u, wo, table):
    """The specular lobe (ggx's visible normals) where u_0 < q, else the cosine, u_0 rescaled
    to [0, 1) within its choice (float32, as kernels/bsdf.h)."""
    table = np.asarray(table, np.float64)
    q = plastic_spec_prob(wo, table).astype(np.float32)
    u0 = np.asarray(u[:, 0], np.float32)
    spec = u0 < q
    with np.errstate(divide="ignore", invalid="ignore"):
        u0 = np.where(spec, u0 / q, (u0 - q) / (np.float32(1) - q)).astype(np.float64)
    uu = np.stack([np.minimum(u0, ONE_MINUS_EPS), u[:, 1]], 1)
    wi = np.where(spec[:, None], ggx_sample(uu, wo, table[:, 3])[0], warp.square_to_cosine_hemisphere(uu))
    return wi, plastic_pdf(wi, wo, table)


ONE_MINUS_EPS = 1.0 - 2.0 ** -24


def _need_table(table):
    if table is None:
        raise ValueError("bsdfs: plastic needs its table rows (plastic_table)")
    return table


# ----------------------------------------------------------------------------- dispatch by type
def eval_cos(kind, param, wi, wo, table=None):
    """f * cos_i without albedo for one material kind; ``param`` is exponent or alpha; plastic:
    specular + diffuse part (:func:`plastic_parts`), from its ``table`` rows."""
    if kind == LAMBERT:
        return lambert_eval(wi)
    if kind == PHONG:
        return phong_eval(wi, wo, param)
    if kind == PLASTIC:
        return plastic_eval(wi, wo, _need_table(table))
    return ggx_eval(wi, wo, param)


def eval_split(kind, param, wi, wo, table=None):
    """(f cos, the part of it the albedo multiplies), both without albedo: for lambert, phong
    and ggx the two are equal; for plastic the second is the diffuse part."""
    if kind == PLASTIC:
        spec, diff = plastic_parts(wi, wo, _need_table(table))
        return spec + diff, diff
    f = eval_cos(kind, param, wi, wo)
    return f, f


def tint(f, diffuse, albedo):
    """The colour (N, 3) that f cos without albedo (``f``, of which ``diffuse`` is multiplied by
    the albedo) is multiplied by to give f cos with albedo: (f - diffuse + albedo diffuse) / f;
    the albedo where f is 0."""
    f, diffuse = np.asarray(f, np.float64)[:, None], np.asarray(diffuse, np.float64)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.where(f > 0, diffuse / f, 1.0)
    return (1.0 - k) + k * np.asarray(albedo, np.float64)


def sample(kind, param, u, wo, table=None):
    """BSDF sampling: lambert cosine, phong lobe, ggx visible normals, plastic one of its two
    lobes. -> (wi, pdf)."""
    if kind == LAMBERT:
        wi = warp.square_to_cosine_hemisphere(u)
        return wi, warp.square_to_cosine_hemisphere_pdf(wi)
    if kind == PHONG:
        return phong_sample(u, wo, param)
    if kind == PLASTIC:
        return plastic_sample(u, wo, _need_table(table))
    return ggx_sample(u, wo, param)


def pdf(kind, param, wi, wo, table=None):
    if kind == LAMBERT:
        return warp.square_to_cosine_hemisphere_pdf(wi)
    if kind == PHONG:
        return phong_pdf(wi, wo, param)
    if kind == PLASTIC:
        return plastic_pdf(wi, wo, _need_table(table))
    return ggx_pdf(wi, wo, param)


# ----------------------------------------------------------------------------- mixed kinds
def lobe_width(kind, param):
    """A lobe's angular width, radians, per item (arrays or scalars): lambert's hemisphere
    pi / 2, phong's 1 / sqrt(n + 1) (its cos^n falls to 1/e there), ggx's 2 alpha (the
    reflected lobe is about twice the microfacet distribution's width); plastic's the
    hemisphere (its diffuse part)."""
    kind, param = np.asarray(kind), np.asarray(param, np.float64)
    width = np.where(kind == GGX, 2.0 * param, np.pi / 2)
    return np.where(kind == PHONG, 1.0 / np.sqrt(np.maximum(param, 0.0) + 1.0), width)


def sample_each(kind, param, u, wo, table=None):
    """:func:`sample` of samples of several materials at once (``kind`` and ``param`` per
    sample; plastic's ``table`` rows per sample): the directions wi (N, 3), one call per
    material kind present."""
    wi = np.zeros((len(kind), 3))
    for kd in np.unique(kind):   # material kinds, not samples
        sel = kind == kd
        wi[sel] = sample(int(kd), param[sel], u[sel], wo[sel], None if table is None else table[sel])[0]
    return wi


def eval_pdf_each(kind, param, wi, wo, table=None, with_diffuse: bool = False):
    """(f * cos_i, pdf) of samples of several materials at once (``kind`` and ``param`` per
    sample; plastic's ``table`` rows per sample), one call per material kind present; with
    ``with_diffuse`` also the part of f cos the albedo multiplies (:func:`eval_split`)."""
    fcos, p, fd = np.zeros(len(kind)), np.zeros(len(kind)), np.zeros(len(kind))
    for kd in np.unique(kind):   # material kinds, not samples
        sel = kind == kd
        rows = None if table is None else table[sel]
        fcos[sel], fd[sel] = eval_split(int(kd), param[sel], wi[sel], wo[sel], rows)
        p[sel] = pdf(int(kd), param[sel], wi[sel], wo[sel], rows)
    return (fcos, p, fd) if with_diffuse else (fcos, p)
