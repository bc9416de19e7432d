"""Plain-numpy reference formulas for the tests, written straight from the papers.

Nothing here imports fitlab: the tests compare fitlab against these independent transcriptions.
Sources: Walter, Marschner, Li, Torrance 2007, "Microfacet Models for Refraction through Rough
Surfaces" (eq. numbers below), Hecht "Optics" (textbook Fresnel equations), Oren & Nayar 1994
(qualitative model). Frame: normal = +z, directions point away from the surface.
"""

from __future__ import annotations

import numpy as np
from scipy.special import erf

# --------------------------------------------------------------------------------------------
# Fresnel
# --------------------------------------------------------------------------------------------


def fresnel_textbook(cos_i, eta):
    """Unpolarized dielectric reflectance from the textbook amplitude coefficients (Hecht):
    r_s = (cos i - η cos t)/(cos i + η cos t), r_p = (η cos i - cos t)/(η cos i + cos t),
    R = (r_s² + r_p²)/2, with η = η_t/η_i and sin t = sin i / η; 1 under total internal reflection."""
    c = np.abs(np.asarray(cos_i, dtype=float))
    eta = np.asarray(eta, dtype=float)
    sin2_t = (1.0 - c * c) / (eta * eta)
    tir = sin2_t >= 1.0
    ct = np.sqrt(np.clip(1.0 - sin2_t, 0.0, None))
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    return np.where(tir, 1.0, 0.5 * (rs * rs + rp * rp))


def fresnel_rs_rp(cos_i, eta):
    """(R_s, R_p) from the same textbook formulas (no total internal reflection)."""
    c = np.abs(np.asarray(cos_i, dtype=float))
    ct = np.sqrt(1.0 - (1.0 - c * c) / (eta * eta))
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    return rs * rs, rp * rp


def fresnel_walter_eq22(cos_i, eta):
    """Walter eq. 22 ([CT82]); g imaginary means total internal reflection, F = 1."""
    c = np.abs(np.asarray(cos_i, dtype=float))
    g2 = eta * eta - 1.0 + c * c
    g = np.sqrt(np.clip(g2, 0.0, None))
    F = 0.5 * (g - c) ** 2 / (g + c) ** 2 * (1.0 + (c * (g + c) - 1.0) ** 2 / (c * (g - c) + 1.0) ** 2)
    return np.where(g2 <= 0.0, 1.0, F)


def fresnel_complex(cos_i, n, k):
    """Unpolarized reflectance of a medium with complex relative index N = n + ik, from the
    textbook amplitude coefficients with complex cos t = sqrt(1 - sin² i / N²)."""
    c = np.abs(np.asarray(cos_i, dtype=float))
    N = np.asarray(n, dtype=float) + 1j * np.asarray(k, dtype=float)
    ct = np.sqrt(1.0 - (1.0 - c * c) / (N * N) + 0j)
    rs = (c - N * ct) / (c + N * ct)
    rp = (N * c - ct) / (N * c + ct)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


# --------------------------------------------------------------------------------------------
# Distributions (Walter section 5.2), for unit m given by θm
# --------------------------------------------------------------------------------------------


def D_ref(name, cos_m, alpha, tan2=None):
    """D(m) of Walter eqs 25 (Beckmann), 30 (Phong, α_p = 2α⁻² - 2), 33 (GGX); 0 for cos_m <= 0.
    Pass tan²θm when known: (1 - cos²)/cos² loses digits near the normal."""
    c = np.asarray(cos_m, dtype=float)
    up = c > 0
    c = np.where(up, c, 1.0)
    if tan2 is None:
        tan2 = (1.0 - c * c) / (c * c)
    if name == "ggx":
        d = alpha**2 / (np.pi * c**4 * (alpha**2 + tan2) ** 2)
    elif name in ("beckmann", "beckmann_rational"):
        d = np.exp(-tan2 / alpha**2) / (np.pi * alpha**2 * c**4)
    elif name == "phong":
        ap = 2.0 / alpha**2 - 2.0
        # cos^α_p = (1 + tan²)^(-α_p/2): c**α_p of a rounded cos near 1 loses digits for α_p ~ 1e6
        d = (ap + 2.0) / (2.0 * np.pi) * np.exp(-0.5 * ap * np.log1p(tan2))
    else:
        raise ValueError(name)
    return np.where(up, d, 0.0)


def G1_ref(name, cos_v, alpha):
    """Smith G1 without the sidedness factor: eq. 34 (GGX), eq. 26 (Beckmann, exact erf), eq. 27
    (rational, also Walter's choice for Phong with a = sqrt(0.5 α_p + 1)/tan θv = 1/(α tan θv))."""
    c = np.abs(np.asarray(cos_v, dtype=float))
    s = np.sqrt(np.clip(1.0 - c * c, 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        tan = s / c
        if name == "ggx":
            return np.where(c > 0, 2.0 / (1.0 + np.sqrt(1.0 + alpha**2 * tan**2)), 0.0)
        a = np.where(s > 0, c / (alpha * s), np.inf)
        if name == "beckmann":
            g = 2.0 / (1.0 + erf(a) + np.exp(-a * a) / (a * np.sqrt(np.pi)))
            return np.where(c > 0, np.where(np.isfinite(a), g, 1.0), 0.0)
        if name in ("beckmann_rational", "phong"):
            r = (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
            return np.where(c > 0, np.where(a < 1.6, r, 1.0), 0.0)
    raise ValueError(name)


def sample_m_ref(name, u1, u2, alpha):
    """Walter eqs 28-29 (Beckmann), 31-32 (Phong), 35-36 (GGX): unit m with density D(m) cos θm."""
    if name == "ggx":
        theta = np.arctan(alpha * np.sqrt(u1 / (1.0 - u1)))
    elif name in ("beckmann", "beckmann_rational"):
        theta = np.arctan(np.sqrt(-(alpha**2) * np.log1p(-u1)))
    elif name == "phong":
        theta = np.arccos(u1 ** (1.0 / (2.0 / alpha**2)))  # 1/(α_p + 2) = α²/2
    else:
        raise ValueError(name)
    phi = 2.0 * np.pi * u2
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


# --------------------------------------------------------------------------------------------
# Full BSDF (Walter eqs 13, 16, 20, 21, 23), incident side +z with η_i = 1 and η_o = eta there
# --------------------------------------------------------------------------------------------


def sph(theta, phi):
    theta, phi = np.asarray(theta, dtype=float), np.asarray(phi, dtype=float)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)


def walter_bsdf(name, alpha, eta_i, eta_t, i, o, fresnel=None):
    """f_r (eq. 20) or f_t (eq. 21) for unit i, o on either side, with the absolute indices eta_i
    (the side of i) and eta_t (the other side, which is o's side for refraction). The
    microfacet normal is the half-vector turned to +z (D is 0 below). ``fresnel(c)`` overrides
    the dielectric eq. 22 (F depends on η_t/η_i)."""
    i, o = np.asarray(i, dtype=float), np.asarray(o, dtype=float)
    ci, co = i[2], o[2]
    if ci * co > 0:  # reflection, eq. 13 with the sign(i·n) factor
        h = np.sign(ci) * (i + o)
    else:  # refraction, eq. 16: h_t = -(η_i i + η_o o), η_o = eta_t, turned to +z
        h = -(eta_i * i + eta_t * o)
        h = h * np.sign(h[2])
    h = h / np.linalg.norm(h)
    ih, oh = i @ h, o @ h
    F = fresnel(abs(ih)) if fresnel is not None else fresnel_walter_eq22(ih, eta_t / eta_i)
    # eq. 23 with the sidedness factors of eqs 26, 27, 34: χ⁺((v·m)/(v·n))
    G = (ih * ci > 0) * (oh * co > 0) * G1_ref(name, ci, alpha) * G1_ref(name, co, alpha)
    D = D_ref(name, h[2], alpha)
    if ci * co > 0:
        return float(F * G * D / (4.0 * abs(ci) * abs(co)))
    return float(
        abs(ih) * abs(oh) / (abs(ci) * abs(co))
        * eta_t**2 * (1.0 - F) * G * D / (eta_i * ih + eta_t * oh) ** 2
    )


def oren_nayar_ref(albedo, sigma, i, o):
    """Oren & Nayar 1994 qualitative model with trigonometry:
    ρ/π (A + B max(0, cos(φi - φo)) sin α tan β), α = max(θi, θo), β = min(θi, θo)."""
    ti, to = np.arccos(i[2]), np.arccos(o[2])
    pi_, po = np.arctan2(i[1], i[0]), np.arctan2(o[1], o[0])
    s2 = sigma * sigma
    A = 1.0 - 0.5 * s2 / (s2 + 0.33)
    B = 0.45 * s2 / (s2 + 0.09)
    a, b = max(ti, to), min(ti, to)
    return albedo / np.pi * (A + B * max(0.0, np.cos(pi_ - po)) * np.sin(a) * np.tan(b))


def refract_ref(i, m, eta):
    """Walter eq. 40 for i·m > 0, with η = η_i/η_t = 1/eta; None under total internal reflection."""
    c = i @ m
    e = 1.0 / eta
    k = 1.0 + e * e * (c * c - 1.0)
    if k < 0:
        return None
    return (e * c - np.sqrt(k)) * m - e * i
