"""The three BRDFs of the scene format: evaluation, sampling and pdf (numpy, local frame).

All functions work on batches in the local shading frame (normal = +z). ``wo`` is
the direction towards the viewer (``wo.z > 0`` after two-sided flipping). ``eval``
returns f(wi, wo) * max(0, cos theta_i), the cosine-weighted BRDF without albedo
colour (a scalar per sample; the albedo multiplies outside). Every ``sample``
returns directions and the exact pdf per unit solid angle that ``pdf`` gives for
the same directions.

| type    | f                                                  | sampling                          |
|---------|----------------------------------------------------|-----------------------------------|
| lambert | albedo / pi                                        | cosine hemisphere                 |
| phong   | albedo (n+2)/(2 pi) max(0, wi.r)^n, r mirror of wo | cos^n lobe about r, (n+1)/(2 pi)  |
| ggx     | albedo D G1(wi) G1(wo) / (4 cos_i cos_o)           | visible normals (Heitz 2018)      |
"""
from __future__ import annotations

import numpy as np

from . import warp

LAMBERT, PHONG, GGX = 0, 1, 2
TYPES = {"lambert": LAMBERT, "phong": PHONG, "ggx": GGX}


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


# ----------------------------------------------------------------------------- dispatch by type
def eval_cos(kind, param, wi, wo):
    """f * cos_i without albedo for one material kind; ``param`` is exponent or alpha."""
    if kind == LAMBERT:
        return lambert_eval(wi)
    if kind == PHONG:
        return phong_eval(wi, wo, param)
    return ggx_eval(wi, wo, param)


def sample(kind, param, u, wo):
    """BSDF sampling: lambert cosine, phong lobe, ggx visible normals. -> (wi, pdf)."""
    if kind == LAMBERT:
        wi = warp.square_to_cosine_hemisphere(u)
        return wi, warp.square_to_cosine_hemisphere_pdf(wi)
    if kind == PHONG:
        return phong_sample(u, wo, param)
    return ggx_sample(u, wo, param)


def pdf(kind, param, wi, wo):
    if kind == LAMBERT:
        return warp.square_to_cosine_hemisphere_pdf(wi)
    if kind == PHONG:
        return phong_pdf(wi, wo, param)
    return ggx_pdf(wi, wo, param)


# ----------------------------------------------------------------------------- mixed kinds
def lobe_width(kind, param):
    """A lobe's angular width, radians, per item (arrays or scalars): lambert's hemisphere
    pi / 2, phong's 1 / sqrt(n + 1) (its cos^n falls to 1/e there), ggx's 2 alpha (the
    reflected lobe is about twice the microfacet distribution's width)."""
    kind, param = np.asarray(kind), np.asarray(param, np.float64)
    width = np.where(kind == GGX, 2.0 * param, np.pi / 2)
    return np.where(kind == PHONG, 1.0 / np.sqrt(np.maximum(param, 0.0) + 1.0), width)


def sample_each(kind, param, u, wo):
    """:func:`sample` of samples of several materials at once (``kind`` and ``param`` per
    sample): the directions wi (N, 3), one call per material kind present."""
    wi = np.zeros((len(kind), 3))
    for kd in np.unique(kind):   # material kinds, not samples
        sel = kind == kd
        wi[sel] = sample(int(kd), param[sel], u[sel], wo[sel])[0]
    return wi


def eval_pdf_each(kind, param, wi, wo):
    """(f * cos_i, pdf) of samples of several materials at once (``kind`` and ``param`` per
    sample), one call per material kind present."""
    fcos, p = np.zeros(len(kind)), np.zeros(len(kind))
    for kd in np.unique(kind):   # material kinds, not samples
        sel = kind == kd
        fcos[sel] = eval_cos(int(kd), param[sel], wi[sel], wo[sel])
        p[sel] = pdf(int(kd), param[sel], wi[sel], wo[sel])
    return fcos, p
