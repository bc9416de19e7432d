"""The OpenPBR model (fitlab/models/openpbr.py) against an independent NumPy transcription of
MaterialX 1.39's GLSL closures (libraries/pbrlib/genglsl: mx_oren_nayar_compensated_diffuse
with L·V unclamped as the spec's EON, mx_dielectric_bsdf, mx_generalized_schlick_bsdf,
mx_sheen_bsdf in Zeltner mode, mx_layer_bsdf) and the graph of open_pbr_surface.mtlx, written
here from those sources with scalar Python arithmetic; plus the energy MaterialX's layering
conserves (seen from a view direction) and reciprocity where the graph is reciprocal (the
EON diffuse alone). The comparison with MaterialX's own generated GLSL is
tests/export/test_materialx.py."""

from __future__ import annotations

import math

import numpy as np
import fitlab
from fitlab.models import get_model

EPS = 1e-8


def _dir(theta, phi):
    t, p = math.radians(theta), math.radians(phi)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def _albedo_fit(x, y):
    """mx_ggx_dir_albedo_analytic's (A, B)."""
    c = np.array([[0.1003, 0.9345, 1.0, 1.0], [-0.6303, -2.323, -1.765, 0.2281],
                  [9.748, 2.229, 8.263, 15.94], [-2.038, -3.748, 11.53, -55.83],
                  [29.34, 1.424, 28.96, 13.08], [-8.245, -0.7684, -7.507, 41.26],
                  [-26.44, 1.436, -36.11, 54.9], [19.99, 0.2913, 15.86, 300.2],
                  [-5.448, 0.6286, 33.37, -285.1]])
    terms = np.array([1, x, y, x * y, x * x, y * y, x * x * y, x * y * y, x * x * y * y])
    r = terms @ c
    return min(max(r[0] / r[2], 0.0), 1.0), min(max(r[1] / r[3], 0.0), 1.0)


def _E(mu, a, f0, f90):
    A, B = _albedo_fit(mu, a)
    return f0 * A + f90 * B


def _fresnel(c, n):
    g2 = n * n + c * c - 1
    if g2 < 0:
        return 1.0
    g = math.sqrt(g2)
    return 0.5 * ((g - c) / (g + c)) ** 2 * (1 + (((g + c) * c - 1) / ((g - c) * c + 1)) ** 2)


def _ggx(L, V, a, F, tint=1.0):
    """(response / N·L, throughput-less) of a GGX closure: D F G comp tint / (4 μi μo)."""
    H = (L + V) / np.linalg.norm(L + V)
    mi, mo = max(L[2], EPS), max(V[2], EPS)
    D = a * a / (math.pi * (H[2] ** 2 * (a * a - 1) + 1) ** 2)
    li = math.sqrt(a * a + (1 - a * a) * mi * mi)
    lo = math.sqrt(a * a + (1 - a * a) * mo * mo)
    G = 2 * mi * mo / (li * mo + lo * mi)
    Ess = _E(mo, a, 1.0, 1.0)
    comp = 1 + F * (1 - Ess) / Ess
    return D * F * G * comp * tint / (4 * mi * mo), comp


def _fon_E(mu, r):
    A = 1 / (1 + (0.5 - 2 / (3 * math.pi)) * r)
    s = math.sqrt(max(0.0, 1 - mu * mu))
    G = s * (math.acos(mu) - s * mu) + 2 * ((s / mu) * (1 - s ** 3) - s) / 3
    return A + r * A * G / math.pi


def _eon(rho, r, L, V):
    mi, mo = L[2], V[2]
    s = float(L @ V) - mi * mo
    st = s / max(mi, mo) if s > 0 else s
    A = 1 / (1 + (0.5 - 2 / (3 * math.pi)) * r)
    ss = rho * A * (1 + r * st)
    Eavg = A * (1 + (2 / 3 - 28 / (15 * math.pi)) * r)
    rho_ms = rho * rho * Eavg / (1 - rho * max(0.0, 1 - Eavg))
    ms = rho_ms * max(EPS, 1 - _fon_E(mo, r)) * max(EPS, 1 - _fon_E(mi, r)) / max(EPS, 1 - Eavg)
    return (ss + ms) / math.pi


def _f82(c, f0, f82):
    x = min(max(c, 0.0), 1.0)
    cm = 1 / 7
    a = (f0 + (1 - f0) * (1 - cm) ** 5) * (1 - f82) / (cm * (1 - cm) ** 6)
    return max(f0 + (1 - f0) * (1 - x) ** 5 - a * x * (1 - x) ** 6, 0.0)


def _sheen(L, V, r, color):
    """sheen_bsdf (Zeltner) response / N·L and its albedo."""
    r = min(max(r, 0.01), 1.0)
    x = max(V[2], EPS)
    y = r
    s = y * (0.0206607 + 1.58491 * y) / (0.0379424 + y * (1.32227 + y))
    m = y * (-0.193854 + y * (-1.14885 + y * (1.7932 - 0.95943 * y * y))) / (0.046391 + y)
    o = y * (0.000654023 + (-0.0207818 + 0.119681 * y) * y) / (1.26264 + y * (-1.92021 + y))
    E = math.exp(-0.5 * ((x - m) / s) ** 2) / (s * math.sqrt(2 * math.pi)) + o
    a_inv = (2.58126 * x + 0.813703 * y) * y / (1 + 0.310327 * x * x + 2.60994 * x * y)
    b_inv = math.sqrt(1 - x) * (y - 1) * y ** 3 / (0.0000254053 + 1.71228 * x - 1.71506 * x * y
                                                  + 1.34174 * y * y)
    X = V - np.array([0, 0, 1.0]) * V[2]
    X = X / np.linalg.norm(X)
    Y = np.cross([0, 0, 1.0], X)
    w = np.array([L @ X, L @ Y, L[2]])
    wo = np.array([a_inv * w[0] + b_inv * w[2], a_inv * w[1], w[2]])
    D = max(wo[2], 0) / math.pi * (a_inv / (wo @ wo)) ** 2
    return color * E * D / max(L[2], EPS), E


def reference(p, L, V):
    """f of open_pbr_surface.mtlx's graph for one directional light, one channel."""
    mi, mo = max(L[2], EPS), max(V[2], EPS)
    H = (L + V) / np.linalg.norm(L + V)
    vh = min(max(float(V @ H), EPS), 1.0)
    cw = p["coat_weight"]
    r_eff = p["specular_roughness"] + cw * (min(1.0, 2 * p["coat_roughness"] ** 4
                                                + p["specular_roughness"] ** 4) ** 0.25
                                            - p["specular_roughness"])
    a = r_eff ** 2
    ratio = p["specular_ior"] / p["coat_ior"]
    ratio = ratio if ratio > 1 else 1 / ratio
    eta_s = p["specular_ior"] + cw * (ratio - p["specular_ior"])
    f0 = min(max(p["specular_weight"] * ((eta_s - 1) / (eta_s + 1)) ** 2, 0), 0.99999)
    e = math.copysign(math.sqrt(f0), eta_s - 1) if eta_s != 1 else 0.0
    eta = (1 + e) / (1 - e)
    Fd = _fresnel(vh, eta)
    spec, comp = _ggx(L, V, a, Fd, p["specular_color"])
    through = 1 - _E(mo, a, ((eta - 1) / (eta + 1)) ** 2, 1.0) * comp
    dielectric = spec + through * p["base_weight"] * _eon(p["base_color"],
                                                          p["base_diffuse_roughness"], L, V)
    Fm = _f82(vh, p["base_weight"] * p["base_color"], p["specular_color"])
    metal = p["specular_weight"] * _ggx(L, V, a, Fm)[0]
    base = dielectric + p["base_metalness"] * (metal - dielectric)
    F0c = ((p["coat_ior"] - 1) / (p["coat_ior"] + 1)) ** 2
    K = 1 - (1 - F0c) / p["coat_ior"] ** 2
    Eb = p["base_color"] + p["base_metalness"] * (p["base_color"] * p["specular_weight"]
                                                   - p["base_color"])
    dark = 1 + cw * p["coat_darkening"] * ((1 - K) / (1 - Eb * K) - 1)
    base *= min(max(dark, 0), 1) * min(max(1 + cw * (p["coat_color"] - 1), 0), 1)
    ac = p["coat_roughness"] ** 2
    coat, comp_c = _ggx(L, V, ac, _fresnel(vh, p["coat_ior"]))
    f = cw * coat + (1 - _E(mo, ac, F0c, 1.0) * comp_c * cw) * base
    fuzz, Ef = _sheen(L, V, p["fuzz_roughness"], p["fuzz_color"])
    return p["fuzz_weight"] * fuzz + (1 - Ef * p["fuzz_weight"]) * f


MODEL = get_model("openpbr")
DEFAULTS = {q.name: q.default for q in MODEL.parameters}
CASES = {
    "default": {},
    "rough_diffuse": {"base_color": 0.7, "base_diffuse_roughness": 0.8},
    "metal_f82": {"base_metalness": 1.0, "base_color": 0.9, "specular_color": 0.4,
                  "specular_roughness": 0.2},
    "coated": {"coat_weight": 0.8, "coat_roughness": 0.3, "coat_color": 0.7,
               "coat_ior": 1.4, "specular_ior": 1.9, "base_color": 0.3},
    "fuzz": {"fuzz_weight": 0.7, "fuzz_roughness": 0.4, "fuzz_color": 0.6,
             "base_diffuse_roughness": 0.3, "specular_weight": 0.6, "base_weight": 0.8},
}
PAIRS = [(_dir(ti, 0.0), _dir(to, po)) for ti, to, po in
         ((0, 30, 0), (30, 30, 180), (45, 60, 100), (70, 20, 250), (80, 85, 180), (10, 75, 45))]


def test_matches_numpy_transcription_of_materialx_closures():
    wi = np.array([a for a, _ in PAIRS])
    wo = np.array([b for _, b in PAIRS])
    for name, extra in CASES.items():
        p = dict(DEFAULTS, **extra)
        got = np.asarray(fitlab.eval_bsdf("openpbr", p, wi, wo))
        want = np.array([reference(p, a, b) for a, b in PAIRS])
        np.testing.assert_allclose(got, want, rtol=1e-10, err_msg=name)


def _grid(n):
    """Midpoint directions of the upper hemisphere in (cos θ, φ) with their solid angles."""
    mu = (np.arange(n) + 0.5) / n
    phi = (np.arange(2 * n) + 0.5) * np.pi / n
    M, P = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - M ** 2)
    w = np.stack([s * np.cos(P), s * np.sin(P), M], -1).reshape(-1, 3)
    return w, np.full(len(w), (1.0 / n) * (np.pi / n))


def test_energy_seen_from_a_view_direction_and_what_a_light_direction_gets():
    """MaterialX's layering scales lower layers by the upper ones' albedo at the view
    direction: ∫ f cos θi dωi over the light directions stays at or below 1 within the albedo
    fits' error (measured: at most 1.020, coated at a 60° view) with white colours; fitlab's albedo at a light direction does not (the
    model declares energy_conserving=False): 1.28 at 85° incidence (the value quoted in
    the model)."""
    w, dw = _grid(96)
    white = {"base_color": 1.0, "specular_color": 1.0, "coat_color": 1.0, "fuzz_color": 1.0}
    for name, extra in CASES.items():
        p = {**DEFAULTS, **extra, **white}
        for theta in (0.0, 60.0, 85.0):
            v = np.broadcast_to(_dir(theta, 0.0), w.shape)
            f = np.asarray(fitlab.eval_bsdf("openpbr", p, w, v))
            seen = float(np.sum(f * w[:, 2] * dw))
            assert seen <= 1.0 + 0.03, f"{name} at view {theta}°: {seen:.4f}"
    p = dict(DEFAULTS, **white)
    light = np.broadcast_to(_dir(85.0, 0.0), w.shape)
    got = float(np.sum(np.asarray(fitlab.eval_bsdf("openpbr", p, light, w)) * w[:, 2] * dw))
    assert 1.2 < got < 1.35, got
    assert not MODEL.capabilities.energy_conserving and not MODEL.capabilities.reciprocal


def test_reciprocal_where_the_graph_is():
    """The spec's EON diffuse lobe (with its multiple-scattering term) is reciprocal; the graph
    as a whole is not: MaterialX scales the diffuse by the dielectric's throughput 1 − E(μo),
    whose F90 = 1 term remains even at specular_weight 0."""
    from fitlab.models.openpbr import eon_diffuse

    rng = np.random.default_rng(5)
    wi = rng.normal(size=(64, 3))
    wo = rng.normal(size=(64, 3))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    for r in (0.0, 0.4, 1.0):
        f_io = np.asarray(eon_diffuse(0.9, r, wi, wo, wi[:, 2], wo[:, 2]))
        f_oi = np.asarray(eon_diffuse(0.9, r, wo, wi, wo[:, 2], wi[:, 2]))
        np.testing.assert_allclose(f_io, f_oi, rtol=1e-12)
    p = dict(DEFAULTS, base_diffuse_roughness=0.6)
    assert np.max(np.abs(np.asarray(fitlab.eval_bsdf("openpbr", p, wi, wo))
                         - np.asarray(fitlab.eval_bsdf("openpbr", p, wo, wi)))) > 1e-4


def test_lambert_limit():
    """base_diffuse_roughness 0: the EON lobe is base_color/π (Lambert), and the graph's f is
    base_weight base_color/π under the specular's throughput, which at specular_weight 0 is
    1 − B(μo, α) (the albedo fit's F90 term)."""
    from fitlab.models.openpbr import eon_diffuse, ggx_dir_albedo

    wi, wo = np.array([_dir(20, 0)]), np.array([_dir(65, 120)])
    np.testing.assert_allclose(np.asarray(eon_diffuse(0.42, 0.0, wi, wo, wi[:, 2], wo[:, 2])),
                               0.42 / np.pi, rtol=1e-6)
    p = dict(DEFAULTS, specular_weight=0.0, base_color=0.42, base_weight=0.5)
    through = 1.0 - float(ggx_dir_albedo(wo[0, 2], 0.3 ** 2, 0.0, 1.0))
    np.testing.assert_allclose(np.asarray(fitlab.eval_bsdf("openpbr", p, wi, wo)),
                               through * 0.5 * 0.42 / np.pi, rtol=1e-6)
