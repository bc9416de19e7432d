"""Agreement with Mitsuba 3 (``roughdielectric``, ``roughconductor``, ``sample_visible: False``).

Mitsuba runs in the ``scalar_rgb`` variant (float32, no LLVM); fitlab in float64 on the same
float32-rounded inputs (directions, α, η = float32(int_ior)/float32(ext_ior), n, k). Every
configuration (distribution × α × index) gets its own fixed-seed random direction pairs: 3/4 in
the lobe (a random microfacet normal within a few α, then reflection or refraction of a random
``wi`` on either side of the surface) and 1/4 uniform over sphere × sphere.

Anisotropic configurations (α given as a pair): Mitsuba's ``alpha_u``, ``alpha_v`` against
fitlab's ``rough_dielectric_anisotropic`` / ``rough_conductor_anisotropic`` with
(alpha_x, alpha_y) = (alpha_u, alpha_v), both along the local frame's +x and +y. The lobe pairs'
microfacet slopes are stretched by (α_u, α_v) and every azimuth is drawn uniformly, so the
pairs probe the lobe off its axes; the same criterion applies, and the test also asserts that
fitlab with the two widths swapped would fail it (the comparison sees the axes). Mitsuba samples
the anisotropic normal's azimuth as φm = atan(α_v/α_u tan 2πu₂) (quadrant of 2πu₂) and
tan²θm with 1/α² = cos²φm/α_u² + sin²φm/α_v²: the same map of the uniforms as fitlab's slope
stretching, so the sample comparison keeps the same u.

* ``eval``. Mitsuba's value includes |cos θo|, and in radiance mode it is a radiance BSDF whose
  ``si.wi`` points toward the camera. Three exact identities are checked:

  - radiance mode, same argument order: ``mi(wi, wo) = f(wi, wo)|cos θo|``, times (η_i/η_o)² on
    transmission (η_i, η_o: the indices on the sides of ``wi`` and ``wo``);
  - radiance mode, swapped (the physical mapping: fitlab's ``wi`` points toward the light, which
    in radiance mode is Mitsuba's ``wo``): ``mi(si.wi=a, wo=b) = f(wi=b, wo=a)|cos b|``, no η
    factor. Both hold because Walter eq. 21 obeys f_t(i, o)/η_o² = f_t(o, i)/η_i²;
  - importance mode, same order: ``mi(wi, wo) = f(wi, wo)|cos θo|``.

* ``pdf`` = fitlab's ``pdf`` with ``sampling='widened'`` for roughdielectric and
  ``sampling='standard'`` for roughconductor: Mitsuba 3.9 widens α only in roughdielectric.

* ``sample`` with the same uniforms: Mitsuba's ``sample(ctx, si, sample1, sample2)`` against
  fitlab's ``u = (sample2.x, sample2.y, sample1)``; the same samples must be valid, and wo,
  weight and pdf must agree. Two documented differences are mapped, not tolerated:

  - incidence from inside (wi.z < 0): Mitsuba reflects/refracts about its upper-hemisphere m
    as is, fitlab mirrors the configuration, so the same u gives m with its azimuth turned by π;
    fitlab's u₂ = sample2.y + 1/2 (mod 1) gives the same m and wo.
  - Mitsuba's roughdielectric weight is Walter eq. 41 *without* the D(m)/D†(m) that widened
    sampling needs, so it is not its own eval·|cos|/pdf: ``mi_weight = weight · D†(m)/D(m)``
    (· (η_i/η_o)² on radiance-mode transmission). The test also checks that Mitsuba's own
    ``eval/pdf`` at its sampled wo equals ``mi_weight · D/D†``, which locates the difference on
    Mitsuba's side. roughconductor does not widen; its weight is its eval/pdf.

Criterion, per configuration and compared quantity: relative difference ≤ 1e-3 on ≥ 99 % of the
pairs that Mitsuba evaluates with its formula, and every larger difference has an asserted
explanation:

* ``cutoff``: Mitsuba's ``MicrofacetDistribution::eval`` returns 0 where D(m) cos θm ≤ 1e-20 (to
  avoid float32 trouble downstream). These pairs are reported, not counted in the 99 %; the test
  asserts fitlab's D(h) cos θh ≤ 1.01e-20 at each (D with the widened α for the pdf).
* ``float32``: the quantity is ill-conditioned at float32 precision, and only at a singular
  geometry. Asserted: (a) the difference is at most ``SENS_FACTOR`` times the relative change of
  fitlab's float64 value when every input moves by one float32 ulp, and (b) some direction is
  within ``GRAZING`` (cosine) of the macrosurface's or the microfacet's horizon, or, for
  sampling, the sampled normal has sin θm < ``NEAR_NORMAL`` (Mitsuba computes sin θm as
  sqrt(1 - cos²θm) in float32). For refraction, a direction grazing the microfacet is the
  critical angle of total internal reflection, where 1 - F has an infinite slope.
* ``negligible``: at a grazing mask boundary one side may return 0 where the other keeps a value
  that goes continuously to 0; asserted ≤ ``NEGLIGIBLE`` × the configuration's median value.
* sampling only: validity or lobe choice may differ where sample1 lies within float32 rounding of
  F(i·m), or where validity itself flips within one ulp of the inputs (both asserted).

``python tests/models/test_mitsuba_agreement.py [--markdown]`` prints the per-configuration figures
quoted in data_formats/MITSUBA_MAPPING.md.
"""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from fitlab.api import eval_bsdf, pdf_bsdf, sample_bsdf
from fitlab.fresnel import fresnel_dielectric_Walter2007
from fitlab.microfacet import widened_alpha, widening_factor
from fitlab.models import get_model

pytestmark = pytest.mark.mitsuba

RTOL = 1e-3  # the criterion: relative difference <= 1e-3 ...
MIN_FRACTION = 0.99  # ... on at least 99 % of the pairs
SENS_FACTOR = 10.0  # a float32 evaluation accumulates several roundings per input ulp
GRAZING = 0.05  # |cos| to the macrosurface or microfacet horizon below which float32 may lose 1e-3
#: sin θm below which Mitsuba's float32 sin θm = sqrt(1 - cos²θm) of a sampled normal is off by
#: more than 1e-4 relative (about 2⁻²³ / sin²θm).
NEAR_NORMAL = float(np.sqrt(2.0**-23 / 1e-4))
NEGLIGIBLE = 1e-5  # relative to the median non-zero value of the configuration
CUTOFF = 1e-20  # Mitsuba's MicrofacetDistribution::eval: D = 0 where D(m) cos θm <= 1e-20
LOBE_CHOICE_TOL = 1e-5  # |sample1 - F(i·m)| within float32 rounding of F

N_DIELECTRIC = 500
N_CONDUCTOR = 300

#: Mitsuba distribution name -> fitlab option (Mitsuba's Beckmann uses Walter's eq. 27 G1).
FITLAB_DISTRIBUTION = {"ggx": "ggx", "beckmann": "beckmann_rational"}

DIELECTRIC_CONFIGS = [  # (distribution, alpha, int_ior, ext_ior); fitlab eta = int_ior / ext_ior
    (dist, alpha, int_ior, ext_ior)
    for dist in ("ggx", "beckmann")
    for alpha in (0.05, 0.2, 0.6)
    for int_ior, ext_ior in ((1.5, 1.0), (1.0, 1.33), (2.4, 1.0))
]
CONDUCTOR_CONFIGS = [  # (distribution, alpha, eta, k); fitlab n = eta
    (dist, alpha, n, k)
    for dist in ("ggx", "beckmann")
    for alpha in (0.05, 0.2, 0.6)
    for n, k in ((0.2, 3.9), (1.5, 0.3), (2.9, 3.2))
]

#: Anisotropic widths (alpha_u, alpha_v) = fitlab (alpha_x, alpha_y): wide along y, wide along
#: x, and one very narrow axis.
ANISO_ALPHAS = ((0.05, 0.4), (0.5, 0.1), (0.3, 0.02))
DIELECTRIC_ANISO_CONFIGS = [  # (distribution, (alpha_u, alpha_v), int_ior, ext_ior)
    (dist, alpha, int_ior, ext_ior)
    for dist in ("ggx", "beckmann")
    for alpha in ANISO_ALPHAS
    for int_ior, ext_ior in ((1.5, 1.0), (1.0, 1.33))
]
CONDUCTOR_ANISO_CONFIGS = [  # (distribution, (alpha_u, alpha_v), eta, k)
    (dist, alpha, n, k)
    for dist in ("ggx", "beckmann")
    for alpha in ANISO_ALPHAS
    for n, k in ((0.2, 3.9), (2.9, 3.2))
]


def _anisotropic(alpha):
    return isinstance(alpha, tuple)


def _alpha_id(alpha):
    return f"aniso{alpha[0]}x{alpha[1]}" if _anisotropic(alpha) else str(alpha)


def _config_id(cfg):
    return "-".join(_alpha_id(c) if j == 1 else str(c) for j, c in enumerate(cfg))


def _seed(kind, cfg):
    return zlib.crc32(f"{kind}:{_config_id(cfg)}".encode())


# ----------------------------------------------------------------------------------------------
# Mitsuba
# ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def mi(mitsuba_scalar):
    return mitsuba_scalar


def _mi_alpha(alpha):
    """Mitsuba's roughness entries: ``alpha``, or ``alpha_u`` and ``alpha_v``."""
    return {"alpha_u": alpha[0], "alpha_v": alpha[1]} if _anisotropic(alpha) else {"alpha": alpha}


def _mi_dielectric(mi, dist, alpha, int_ior, ext_ior):
    return mi.load_dict({"type": "roughdielectric", "distribution": dist, **_mi_alpha(alpha),
                         "int_ior": int_ior, "ext_ior": ext_ior, "sample_visible": False})


def _mi_conductor(mi, dist, alpha, n, k):
    return mi.load_dict({"type": "roughconductor", "distribution": dist, **_mi_alpha(alpha),
                         "eta": n, "k": k, "sample_visible": False})


def _mi_eval_pdf(mi, bsdf, wi, wo, mode):
    """Mitsuba's eval (first channel) and pdf, one scalar call per pair."""
    ctx = mi.BSDFContext(mode)
    si = mi.SurfaceInteraction3f()
    ev = np.empty(len(wi))
    pdf = np.empty(len(wi))
    for j in range(len(wi)):
        si.wi = mi.Vector3f(wi[j])
        value, p = bsdf.eval_pdf(ctx, si, mi.Vector3f(wo[j]))
        ev[j] = value[0]
        pdf[j] = p
    return ev, pdf


def _mi_sample(mi, bsdf, wi, u):
    """Mitsuba's sample(ctx, si, sample1=u[2], sample2=(u[0], u[1])) in radiance mode."""
    ctx = mi.BSDFContext(mi.TransportMode.Radiance)
    si = mi.SurfaceInteraction3f()
    wo = np.empty((len(wi), 3))
    weight = np.empty(len(wi))
    pdf = np.empty(len(wi))
    for j in range(len(wi)):
        si.wi = mi.Vector3f(wi[j])
        bs, w = bsdf.sample(ctx, si, float(u[j, 2]), mi.Point2f(float(u[j, 0]), float(u[j, 1])))
        wo[j] = (bs.wo[0], bs.wo[1], bs.wo[2])
        weight[j] = w[0]
        pdf[j] = bs.pdf
    return wo, weight, pdf


# ----------------------------------------------------------------------------------------------
# Geometry helpers
# ----------------------------------------------------------------------------------------------


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _uniform_sphere(rng, n):
    z = rng.uniform(-1.0, 1.0, n)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    s = np.sqrt(1.0 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


def _direction_pairs(rng, n, alpha, eta, transmit_fraction, lower_fraction):
    """float32 (wi, wo): 3/4 in the lobe around a random microfacet normal, 1/4 uniform.

    ``alpha``: the width, or the widths (α_u, α_v) that stretch the normal's slope along x and y;
    ``eta`` = n_inside / n_outside; a ``lower_fraction`` of the lobe pairs has wi below the
    surface; a ``transmit_fraction`` of them refracts (where there is no TIR)."""
    alpha_x, alpha_y = alpha if _anisotropic(alpha) else (alpha, alpha)
    n_lobe = 3 * n // 4
    wi = _uniform_sphere(rng, n_lobe)
    below = rng.uniform(size=n_lobe) < lower_fraction
    wi[:, 2] = np.where(below, -np.abs(wi[:, 2]), np.abs(wi[:, 2]))
    g = np.abs(rng.normal(size=n_lobe))
    tan_x, tan_y = 1.5 * alpha_x * g, 1.5 * alpha_y * g
    phi = rng.uniform(0.0, 2.0 * np.pi, n_lobe)
    side = np.where(below, -1.0, 1.0)
    m = _unit(np.stack([tan_x * np.cos(phi), tan_y * np.sin(phi), side], axis=-1))
    c = np.sum(wi * m, axis=-1)
    wo_r = 2.0 * c[:, None] * m - wi
    inv = np.where(below, eta, 1.0 / eta)  # η_i / η_t
    k = 1.0 + inv**2 * (c * c - 1.0)
    wo_t = (inv * c - np.sign(c) * np.sqrt(np.maximum(k, 0.0)))[:, None] * m - inv[:, None] * wi
    use_t = (rng.uniform(size=n_lobe) < transmit_fraction) & (k > 0)
    wo = np.where(use_t[:, None], wo_t, wo_r)
    wi = np.concatenate([wi, _uniform_sphere(rng, n - n_lobe)])
    wo = np.concatenate([wo, _uniform_sphere(rng, n - n_lobe)])
    return _unit(wi).astype(np.float32), _unit(wo).astype(np.float32)


def _half_vector(wi, wo, eta=None):
    """Unit (generalized) half-vector in the +z hemisphere: Walter eq. 13 for reflection, eq. 16
    for refraction (``eta`` = n_inside / n_outside; None for a conductor)."""
    reflect = wi[:, 2] * wo[:, 2] > 0
    if eta is None:
        scale = np.ones(len(wi))
    else:
        scale = np.where(reflect, 1.0, np.where(wi[:, 2] > 0, eta, 1.0 / eta))  # η_o / η_i
    h = wi + scale[:, None] * wo
    return _unit(h * np.where(h[:, 2] < 0, -1.0, 1.0)[:, None])


def _ndf(model, fdist, params, cos_i=None):
    """The model's microfacet distribution with the widths in ``params`` (asked of the model);
    with ``cos_i``, Walter's widened one (section 5.3) for that incidence."""
    dist = get_model(model).microfacet(params, distribution=fdist)
    return dist if cos_i is None else dist.scaled(widening_factor(cos_i))


def _D_cos(dist, h):
    """fitlab's D(h) cos θh, the quantity Mitsuba's cutoff tests."""
    return np.asarray(dist.D(h)) * h[:, 2]


def _grazing(wi, wo, h):
    """Smallest |cos| of either direction to the macrosurface or the microfacet h."""
    return np.min(np.abs(np.stack(
        [wi[:, 2], wo[:, 2], np.sum(wi * h, axis=-1), np.sum(wo * h, axis=-1)])), axis=0)


# ----------------------------------------------------------------------------------------------
# float32 sensitivity and the criterion
# ----------------------------------------------------------------------------------------------


def _relative_difference(a, b):
    scale = np.maximum(np.abs(a), np.abs(b))
    return np.where(scale > 0, np.abs(a - b) / np.where(scale > 0, scale, 1.0), 0.0)


def _rel_sensitivity(f0, fk):
    """max_k |fk - f0| / max(|f0|, |fk|): 1 where a perturbation toggles zero / non-zero."""
    scale = np.maximum(np.abs(f0), np.max(np.abs(fk), axis=0))
    change = np.max(np.abs(fk - f0), axis=0)
    return np.where(scale > 0, change / np.where(scale > 0, scale, 1.0), 0.0)


def _ulp_jitter(rng, x):
    return x * (1.0 + rng.uniform(-1.0, 1.0, x.shape) * 2.0**-23)


def _eval_sensitivity(fn, params, wi, wo, rng, k=8):
    """Relative change of fn(params, wi, wo), evaluated in float64, when wi, wo and the
    parameters move by up to one float32 ulp (2⁻²³ relative): the difference a float32
    implementation of the same formula can legitimately show, up to a few roundings."""
    n = len(wi)
    p0 = {name: np.full(n, v) for name, v in params.items()}
    big_p = {name: np.concatenate([v] + [_ulp_jitter(rng, v) for _ in range(k)])
             for name, v in p0.items()}
    big_wi = np.concatenate([wi] + [_ulp_jitter(rng, wi) for _ in range(k)])
    big_wo = np.concatenate([wo] + [_ulp_jitter(rng, wo) for _ in range(k)])
    f = np.asarray(fn(big_p, big_wi, big_wo)).reshape(k + 1, n)
    return _rel_sensitivity(f[0], f[1:])


def _check(label, ours, theirs, *, sens, singular, cutoff_ok=None):
    """Assert the criterion (module docstring) and return the figures.

    ``sens``: float32 sensitivity per pair; ``singular``: pairs at a geometry where float32 is
    known to lose digits (grazing; for sampling also a normal close to +z);
    ``cutoff_ok``: pairs where fitlab's D cos θ is under Mitsuba's cutoff (None: no cutoff)."""
    rel = _relative_difference(ours, theirs)
    # Mitsuba's zero by its D cutoff; any other zero mismatch must be explained like the rest.
    cut = (theirs == 0) & (ours != 0)
    cut &= cutoff_ok if cutoff_ok is not None else False
    formula = ~cut
    fraction = np.sum((rel <= RTOL) & formula) / max(formula.sum(), 1)
    assert fraction >= MIN_FRACTION, (
        f"{label}: only {fraction:.4f} of {formula.sum()} pairs within {RTOL:g} "
        f"(99th percentile {np.quantile(rel[formula], 0.99):.2e})")
    larger = formula & (rel > RTOL)
    explained = larger & (rel <= SENS_FACTOR * sens) & singular
    # At a grazing mask boundary (i·h or o·h = 0) the value goes continuously to 0, so one side
    # may mask a value the other keeps: both are then negligible next to the lobe.
    scale = np.median(np.abs(theirs[theirs != 0])) if np.any(theirs != 0) else 0.0
    negligible = larger & ~explained & singular & (
        np.maximum(np.abs(ours), np.abs(theirs)) <= NEGLIGIBLE * scale)
    unexplained = larger & ~explained & ~negligible
    assert not unexplained.any(), (
        f"{label}: unexplained differences > {RTOL:g} at pairs {np.nonzero(unexplained)[0][:10]}: "
        f"fitlab {ours[unexplained][:5]}, mitsuba {theirs[unexplained][:5]}, relative "
        f"{rel[unexplained][:5]}, float32 sensitivity {sens[unexplained][:5]}, "
        f"singular geometry {singular[unexplained][:5]}")
    q = rel[formula] if formula.any() else np.zeros(1)
    return {"label": label, "n": len(rel), "q99": float(np.quantile(q, 0.99)),
            "max": float(q.max()), "fraction": float(fraction),
            "fraction_all": float(np.mean(rel <= RTOL)), "cutoff": int(cut.sum()),
            "float32": int(explained.sum()), "negligible": int(negligible.sum())}


# ----------------------------------------------------------------------------------------------
# eval and pdf
# ----------------------------------------------------------------------------------------------


def _widths(alpha):
    """fitlab's roughness parameters, float32-rounded as Mitsuba stores them."""
    if _anisotropic(alpha):
        return {"alpha_x": float(np.float32(alpha[0])), "alpha_y": float(np.float32(alpha[1]))}
    return {"alpha": float(np.float32(alpha))}


def _dielectric_setup(cfg):
    """(fitlab model, distribution, parameters) of a roughdielectric configuration."""
    dist, alpha, int_ior, ext_ior = cfg
    # scalar_rgb stores eta = int_ior / ext_ior as a float32 quotient of float32s, α in float32
    eta = float(np.float32(int_ior) / np.float32(ext_ior))
    model = "rough_dielectric_anisotropic" if _anisotropic(alpha) else "rough_dielectric"
    return model, FITLAB_DISTRIBUTION[dist], {**_widths(alpha), "eta": eta}


def _conductor_setup(cfg):
    """(fitlab model, distribution, parameters) of a roughconductor configuration."""
    dist, alpha, n, k = cfg
    model = "rough_conductor_anisotropic" if _anisotropic(alpha) else "rough_conductor"
    return model, FITLAB_DISTRIBUTION[dist], {**_widths(alpha), "n": float(np.float32(n)),
                                              "k": float(np.float32(k))}


def _compare_eval_pdf(mi, bsdf, tag, model, fdist, sampling, params, wi32, wo32, eta, rng):
    """The three eval identities and the pdf (module docstring) on the pairs (wi32, wo32)."""
    mi_rad, mi_pdf = _mi_eval_pdf(mi, bsdf, wi32, wo32, mi.TransportMode.Radiance)
    mi_imp, _ = _mi_eval_pdf(mi, bsdf, wi32, wo32, mi.TransportMode.Importance)
    wi, wo = wi32.astype(np.float64), wo32.astype(np.float64)
    opts = {"distribution": fdist}

    def f_cos(p, a, b):  # f(a, b)|cos θ_b|: Mitsuba's importance-mode value
        return eval_bsdf(model, p, a, b, opts) * np.abs(b[..., 2])

    def f_cos_radiance(p, a, b):  # same order in radiance mode: (η_i/η_o)² on transmission
        if "eta" not in p:
            return f_cos(p, a, b)
        eta_i_over_o = np.where(a[..., 2] > 0, 1.0 / p["eta"], p["eta"])
        trans = a[..., 2] * b[..., 2] < 0
        return f_cos(p, a, b) * np.where(trans, eta_i_over_o**2, 1.0)

    def f_cos_swapped(p, a, b):  # radiance mode, physical mapping: f(wi=b, wo=a)|cos b|
        return eval_bsdf(model, p, b, a, opts) * np.abs(b[..., 2])

    def pdf_fn(p, a, b):
        return pdf_bsdf(model, p, a, b, {"distribution": fdist, "sampling": sampling})

    h = _half_vector(wi, wo, eta)
    grazing = _grazing(wi, wo, h)
    cut_eval = _D_cos(_ndf(model, fdist, params), h) <= CUTOFF * 1.01
    cut_pdf = _D_cos(_ndf(model, fdist, params, wi[:, 2] if sampling == "widened" else None),
                     h) <= CUTOFF * 1.01
    # Mitsuba always evaluates in the given order, so that order's conditioning bounds its
    # rounding; the swapped comparison takes the worse of the two orders.
    sens_same = _eval_sensitivity(f_cos_radiance, params, wi, wo, rng)
    out = []
    for name, fn, theirs, cut_ok, sens in (
        ("eval radiance", f_cos_radiance, mi_rad, cut_eval, sens_same),
        ("eval radiance swapped", f_cos_swapped, mi_rad, cut_eval,
         np.maximum(sens_same, _eval_sensitivity(f_cos_swapped, params, wi, wo, rng))),
        ("eval importance", f_cos, mi_imp, cut_eval,
         _eval_sensitivity(f_cos, params, wi, wo, rng)),
        (f"pdf {sampling}", pdf_fn, mi_pdf, cut_pdf,
         _eval_sensitivity(pdf_fn, params, wi, wo, rng)),
    ):
        ours = np.asarray(fn(params, wi, wo))
        if eta is None:  # roughconductor is one-sided, like fitlab's rough_conductor
            both_up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
            assert np.all(theirs[~both_up] == 0) and np.all(ours[~both_up] == 0), f"{tag} {name}"
        out.append(_check(f"{tag} {name}", ours, theirs, sens=sens,
                          singular=grazing < GRAZING, cutoff_ok=cut_ok))
    if "alpha_x" in params:
        # The comparison sees the axes: fitlab with α_x and α_y swapped fails the criterion.
        swapped = {**params, "alpha_x": params["alpha_y"], "alpha_y": params["alpha_x"]}
        rel = _relative_difference(np.asarray(f_cos(swapped, wi, wo)), mi_imp)
        fraction = float(np.mean(rel[~cut_eval] <= RTOL))
        assert fraction < MIN_FRACTION, f"{tag}: insensitive to the axes ({fraction:.4f})"
        out[0]["swapped_axes_fraction"] = fraction
    return out


def run_dielectric_eval_pdf(mi, cfg, n=N_DIELECTRIC):
    model, fdist, params = _dielectric_setup(cfg)
    rng = np.random.default_rng(_seed("dielectric-eval", cfg))
    wi32, wo32 = _direction_pairs(rng, n, cfg[1], params["eta"], transmit_fraction=0.5,
                                  lower_fraction=0.5)
    return _compare_eval_pdf(mi, _mi_dielectric(mi, *cfg), f"roughdielectric {_config_id(cfg)}",
                             model, fdist, "widened", params, wi32, wo32, params["eta"], rng)


def run_conductor_eval_pdf(mi, cfg, n=N_CONDUCTOR):
    model, fdist, params = _conductor_setup(cfg)
    rng = np.random.default_rng(_seed("conductor-eval", cfg))
    # 10 % of the lobe pairs (and half the uniform ones) have wi below: both must give 0 there.
    wi32, wo32 = _direction_pairs(rng, n, cfg[1], 1.0, transmit_fraction=0.0, lower_fraction=0.1)
    return _compare_eval_pdf(mi, _mi_conductor(mi, *cfg), f"roughconductor {_config_id(cfg)}",
                             model, fdist, "standard", params, wi32, wo32, None, rng)


# ----------------------------------------------------------------------------------------------
# sample
# ----------------------------------------------------------------------------------------------


def _sin2_theta_m(fdist, u1, alpha_s):
    """sin²θm of the microfacet normal sampled from u1 (Walter eqs 28, 35)."""
    a2 = alpha_s * alpha_s
    if fdist == "ggx":
        return a2 * u1 / (1.0 - u1 + a2 * u1)
    t2 = -a2 * np.log1p(-u1)
    return t2 / (1.0 + t2)


def _u1_from_sin2(fdist, s2, alpha_s):
    """Inverse of :func:`_sin2_theta_m`."""
    a2 = alpha_s * alpha_s
    s2 = np.clip(s2, 0.0, 1.0 - 2.0**-24)
    if fdist == "ggx":
        return s2 / (a2 * (1.0 - s2) + s2)
    return -np.expm1(-s2 / (1.0 - s2) / a2)


def _sampling_width(params, cos_i, u2, widened):
    """The width with which the normal sampled from u₂ gets its tan²θm (Walter eqs 28, 35):
    α, or for α_x ≠ α_y the width along the sampled slope azimuth φ = 2πu₂,
    sqrt(α_x² cos²φ + α_y² sin²φ) (Heitz 2014 section 5.3); widened where ``widened``."""
    if "alpha" in params:
        alpha = params["alpha"]
    else:
        phi = 2.0 * np.pi * u2
        alpha = np.hypot(params["alpha_x"] * np.cos(phi), params["alpha_y"] * np.sin(phi))
    return np.asarray(widened_alpha(alpha, cos_i)) if widened else alpha


def _sample_perturbed(fn, params, wi, u, rng, fdist, widened, k=8):
    """fn(params, wi, u) -> (n, c) at the inputs and at k perturbations of one float32 ulp:
    2⁻²³ relative on wi and the parameters; on the uniforms 2⁻²⁴ absolute (Mitsuba's float32
    1 - u) and 2⁻²³ on u₂ (its float32 2πu₂); and 2⁻²² absolute on the sampled normal's sin²θm:
    Mitsuba forms cos θm = rsqrt(1 + tan²θm), squares it and takes sin θm = sqrt(1 - cos²θm) in
    float32, three roundings near 1 that for a normal near +z lose most digits of sin θm (for
    tan²θm of order 1e-7 it samples m = +z exactly)."""
    n = len(wi)
    ps, wis, us = [{name: np.full(n, v) for name, v in params.items()}], [wi], [u]
    for _ in range(k):
        p = {name: _ulp_jitter(rng, v) for name, v in ps[0].items()}
        w = _ulp_jitter(rng, wi)
        a_s = _sampling_width(p, w[:, 2], u[:, 1], widened)
        s2 = _sin2_theta_m(fdist, u[:, 0], a_s) + rng.uniform(-1.0, 1.0, n) * 2.0**-22
        u1 = _u1_from_sin2(fdist, s2, a_s) + rng.uniform(-1.0, 1.0, n) * 2.0**-24
        u2 = u[:, 1] + rng.uniform(-1.0, 1.0, n) * 2.0**-23
        ps.append(p)
        wis.append(w)
        us.append(np.clip(np.stack([u1, u2, u[:, 2]], axis=-1), 0.0, 1.0 - 2.0**-24))
    big_p = {name: np.concatenate([p[name] for p in ps]) for name in params}
    f = np.asarray(fn(big_p, np.concatenate(wis), np.concatenate(us))).reshape(k + 1, n, -1)
    return f[0], f[1:]


def _widened_ratio(model, fdist, params, wi, u):
    """D†(m)/D(m) and m, for the normal sampled from u with the widened width (Walter §5.3)."""
    dist, dist_s = _ndf(model, fdist, params), _ndf(model, fdist, params, wi[..., 2])
    m = np.asarray(dist_s.sample_m(u))
    return np.asarray(dist_s.D(m)) / np.asarray(dist.D(m)), m


def _compare_samples(mi, bsdf, tag, outputs, params, wi32, u32, u_fit, lobe_edge, fdist,
                     widened, eta):
    """Both samplers on the same inputs: validity, wo, weight and pdf.

    ``outputs(params, wi, u) -> (n, 5)``: fitlab's wo, its weight in Mitsuba's convention, pdf.
    Returns the figures and Mitsuba's (wo, weight) and the mask of samples both accept."""
    rng = np.random.default_rng(zlib.crc32(tag.encode()))
    mi_wo, mi_w, mi_pdf = _mi_sample(mi, bsdf, wi32, u32)
    wi = wi32.astype(np.float64)
    f0, fk = _sample_perturbed(outputs, params, wi, u_fit, rng, fdist, widened)
    wo, w, pdf = f0[:, :3], f0[:, 3], f0[:, 4]
    sens_w = _rel_sensitivity(f0[:, 3], fk[:, :, 3])
    sens_pdf = _rel_sensitivity(f0[:, 4], fk[:, :, 4])
    sens_wo = np.max(np.abs(fk[:, :, :3] - f0[None, :, :3]), axis=(0, 2))
    # float32-singular: grazing, or a sampled normal close to +z (Mitsuba's float32 sin θm)
    a_s = _sampling_width(params, wi[:, 2], u_fit[:, 1], widened)
    singular = (_grazing(wi, wo, _half_vector(wi, wo, eta)) < GRAZING) | (
        _sin2_theta_m(fdist, u_fit[:, 0], a_s) < NEAR_NORMAL**2)

    ok_mi, ok_ours = mi_w > 0, w > 0
    differ = ok_mi != ok_ours
    unexplained = differ & ~lobe_edge & (sens_w < 0.5)
    assert not unexplained.any(), (
        f"{tag}: validity differs at {np.nonzero(unexplained)[0][:10]} "
        f"(mitsuba weight {mi_w[unexplained][:5]}, fitlab {w[unexplained][:5]})")
    both = ok_mi & ok_ours & ~lobe_edge
    wo_diff = np.max(np.abs(wo - mi_wo), axis=-1)
    bad_wo = both & (wo_diff > RTOL) & ~((wo_diff <= SENS_FACTOR * sens_wo) & singular)
    assert not bad_wo.any(), (
        f"{tag}: wo differs at {np.nonzero(bad_wo)[0][:10]}: {wo_diff[bad_wo][:5]}")
    res = _check(f"{tag} weight", w[both], mi_w[both], sens=sens_w[both],
                 singular=singular[both])
    res_pdf = _check(f"{tag} pdf", pdf[both], mi_pdf[both], sens=sens_pdf[both],
                     singular=singular[both])
    res.update(valid=int(both.sum()), validity_differs=int(differ.sum()),
               lobe_edge=int(lobe_edge.sum()), wo_max_abs=float(wo_diff[both].max(initial=0.0)))
    return [res, res_pdf], (mi_wo, mi_w, both)


def run_dielectric_sample(mi, cfg, n=N_DIELECTRIC):
    model, fdist, params = _dielectric_setup(cfg)
    eta = params["eta"]
    rng = np.random.default_rng(_seed("dielectric-sample", cfg))
    wi32 = _unit(_uniform_sphere(rng, n)).astype(np.float32)
    u32 = rng.uniform(0.0, 1.0, (n, 3)).astype(np.float32)
    wi, u = wi32.astype(np.float64), u32.astype(np.float64)
    inside = wi[:, 2] < 0
    # Inside incidence: Mitsuba uses its upper-hemisphere m as is; fitlab mirrors the
    # configuration, which turns the same m's azimuth by π: sample2.y + 1/2 (mod 1) compensates.
    u_fit = u.copy()
    u_fit[inside, 1] = np.mod(u_fit[inside, 1] + 0.5, 1.0)

    def outputs(p, a, uu):
        wo, weight, pdf = (np.asarray(x) for x in sample_bsdf(
            model, p, a, uu, {"distribution": fdist, "sampling": "widened"}))
        d_ratio, _ = _widened_ratio(model, fdist, p, a, uu)  # Mitsuba's weight lacks D/D†
        trans = a[:, 2] * wo[:, 2] < 0
        radiance = np.where(trans, np.where(a[:, 2] > 0, 1.0 / p["eta"], p["eta"]) ** 2, 1.0)
        return np.concatenate([wo, (weight * d_ratio * radiance)[:, None], pdf[:, None]], axis=-1)

    # Lobe choice: sample1 against F(i·m) in fitlab's upper frame (η_t/η_i = eta or 1/eta).
    d_ratio, m = _widened_ratio(model, fdist, params, wi, u_fit)
    wi_up = np.concatenate([wi[:, :2], np.abs(wi[:, 2:])], axis=-1)
    F = np.asarray(fresnel_dielectric_Walter2007(np.sum(wi_up * m, axis=-1),
                                                 np.where(inside, 1.0 / eta, eta)))
    lobe_edge = np.abs(u[:, 2] - F) <= LOBE_CHOICE_TOL

    bsdf = _mi_dielectric(mi, *cfg)
    tag = f"roughdielectric {_config_id(cfg)} sample"
    res, (mi_wo, mi_w, both) = _compare_samples(mi, bsdf, tag, outputs, params, wi32, u32, u_fit,
                                                lobe_edge, fdist, True, eta)

    # Mitsuba's own eval/pdf at its sampled wo is its weight times D/D†: the factor that makes
    # the two samplers' weights differ is missing on Mitsuba's side.
    ev, pd = _mi_eval_pdf(mi, bsdf, wi32, mi_wo.astype(np.float32), mi.TransportMode.Radiance)
    own = ev[both] / pd[both]
    rel_fixed = _relative_difference(own, mi_w[both] / d_ratio[both])
    assert np.mean(rel_fixed <= RTOL) >= MIN_FRACTION, (
        f"{tag}: Mitsuba's eval/pdf != its weight · D/D† (99th percentile "
        f"{np.quantile(rel_fixed, 0.99):.2e})")
    res[0]["mitsuba_weight_vs_its_eval_over_pdf_max"] = float(
        _relative_difference(own, mi_w[both]).max(initial=0.0))
    return res


def run_conductor_sample(mi, cfg, n=N_CONDUCTOR):
    model, fdist, params = _conductor_setup(cfg)
    rng = np.random.default_rng(_seed("conductor-sample", cfg))
    wi32 = _unit(_uniform_sphere(rng, n)).astype(np.float32)
    wi32[:, 2] = np.where(rng.uniform(size=n) < 0.9, np.abs(wi32[:, 2]), -np.abs(wi32[:, 2]))
    u32 = rng.uniform(0.0, 1.0, (n, 3)).astype(np.float32)

    def outputs(p, a, uu):  # sample1 unused by both; no widening; weight = eval·cos/pdf
        wo, weight, pdf = (np.asarray(x) for x in sample_bsdf(
            model, p, a, uu, {"distribution": fdist, "sampling": "standard"}))
        return np.concatenate([wo, weight[:, None], pdf[:, None]], axis=-1)

    tag = f"roughconductor {_config_id(cfg)} sample"
    res, _ = _compare_samples(mi, _mi_conductor(mi, *cfg), tag, outputs, params, wi32, u32,
                              u32.astype(np.float64), np.zeros(n, bool), fdist, False, None)
    return res


# ----------------------------------------------------------------------------------------------
# Tests
# ----------------------------------------------------------------------------------------------


def _print_figures(rows):
    """The figures of one configuration (seen with ``pytest -s``): per compared quantity the
    fraction of pairs within RTOL (of those Mitsuba evaluates with its formula) and the largest
    relative difference among them."""
    for r in rows:
        extra = "".join(f" {k}={r[k]:.4f}" for k in ("swapped_axes_fraction",) if k in r)
        print(f"\n{r['label']}: within {RTOL:g} {r['fraction']:.4f} of {r['n'] - r['cutoff']} "
              f"(max rel {r['max']:.2e}, q99 {r['q99']:.2e}; cutoff {r['cutoff']}, "
              f"float32 {r['float32']}, negligible {r['negligible']}){extra}", end="")


ALL_DIELECTRIC_CONFIGS = DIELECTRIC_CONFIGS + DIELECTRIC_ANISO_CONFIGS
ALL_CONDUCTOR_CONFIGS = CONDUCTOR_CONFIGS + CONDUCTOR_ANISO_CONFIGS


@pytest.mark.parametrize("cfg", ALL_DIELECTRIC_CONFIGS, ids=_config_id)
def test_roughdielectric_eval_pdf(mi, cfg):
    _print_figures(run_dielectric_eval_pdf(mi, cfg))


@pytest.mark.parametrize("cfg", ALL_DIELECTRIC_CONFIGS, ids=_config_id)
def test_roughdielectric_sample(mi, cfg):
    _print_figures(run_dielectric_sample(mi, cfg))


@pytest.mark.parametrize("cfg", ALL_CONDUCTOR_CONFIGS, ids=_config_id)
def test_roughconductor_eval_pdf(mi, cfg):
    _print_figures(run_conductor_eval_pdf(mi, cfg))


@pytest.mark.parametrize("cfg", ALL_CONDUCTOR_CONFIGS, ids=_config_id)
def test_roughconductor_sample(mi, cfg):
    _print_figures(run_conductor_sample(mi, cfg))


def test_worked_example(mi):
    """The worked example of MITSUBA_MAPPING.md: GGX, α = 0.3, η = 1.5, light from outside."""
    bsdf = _mi_dielectric(mi, "ggx", 0.3, 1.5, 1.0)
    a = np.array([[0.3, 0.1, np.sqrt(0.9)]], np.float32)  # above the surface
    b = np.array([[-0.3, 0.2, -np.sqrt(0.87)]], np.float32)  # below
    p = {"alpha": 0.3, "eta": 1.5}
    (rad,), (pdf,) = _mi_eval_pdf(mi, bsdf, a, b, mi.TransportMode.Radiance)
    (imp,), _ = _mi_eval_pdf(mi, bsdf, a, b, mi.TransportMode.Importance)
    f_ab = float(eval_bsdf("rough_dielectric", p, a.astype(float), b.astype(float))[0])
    f_ba = float(eval_bsdf("rough_dielectric", p, b.astype(float), a.astype(float))[0])
    cos_b = abs(float(b[0, 2]))
    assert rad == pytest.approx(f_ab * cos_b / 1.5**2, rel=1e-5)  # same order: (η_i/η_o)²
    assert rad == pytest.approx(f_ba * cos_b, rel=1e-5)  # swapped: the physical mapping
    assert imp == pytest.approx(f_ab * cos_b, rel=1e-5)
    ours_pdf = float(pdf_bsdf("rough_dielectric", p, a.astype(float), b.astype(float),
                              {"sampling": "widened"})[0])
    assert pdf == pytest.approx(ours_pdf, rel=1e-5)


# ----------------------------------------------------------------------------------------------
# Figures for data_formats/MITSUBA_MAPPING.md
# ----------------------------------------------------------------------------------------------


def _print_table(rows):
    print(f"{'comparison':58s} {'pairs':>5s} {'q99':>8s} {'max':>8s} {'<=1e-3':>7s} {'all':>7s} "
          f"{'cut':>4s} {'f32':>4s} {'negl':>4s}  extra")
    base = ("label", "n", "q99", "max", "fraction", "fraction_all", "cutoff", "float32",
            "negligible")
    for r in rows:
        extra = " ".join(f"{k}={v:.2g}" if isinstance(v, float) else f"{k}={v}"
                         for k, v in r.items() if k not in base)
        print(f"{r['label']:58s} {r['n']:5d} {r['q99']:8.1e} {r['max']:8.1e} "
              f"{r['fraction']:7.4f} {r['fraction_all']:7.4f} {r['cutoff']:4d} {r['float32']:4d} "
              f"{r['negligible']:4d}  "
              f"{extra}")


def _markdown_row(model, cfg, rows):
    """One configuration as a row of the table in MITSUBA_MAPPING.md."""
    by = {r["label"].split(" ", 2)[2]: r for r in rows}

    def qm(name):
        return f"{by[name]['q99']:.1e} / {by[name]['max']:.1e}"

    index = f"{cfg[2]}/{cfg[3]}" if model == "roughdielectric" else f"{cfg[2]}+{cfg[3]}i"
    alpha = f"{cfg[1][0]}, {cfg[1][1]}" if _anisotropic(cfg[1]) else cfg[1]
    pdf = "pdf widened" if model == "roughdielectric" else "pdf standard"
    worst = min(r["fraction"] for r in rows)
    explained = "/".join(str(sum(r[k] for r in rows)) for k in ("float32", "negligible"))
    pairs = by["eval radiance"]["n"]
    return (f"| {model} | {cfg[0]} | {alpha} | {index} | {pairs} | {qm('eval radiance')} | "
            f"{by['eval radiance swapped']['max']:.1e} | {qm(pdf)} | {qm('sample weight')} | "
            f"{qm('sample pdf')} | {by['sample weight']['wo_max_abs']:.1e} | {worst:.4f} | "
            f"{by['eval radiance']['cutoff']} | {explained} |")


if __name__ == "__main__":
    import sys

    import jax
    import mitsuba

    jax.config.update("jax_enable_x64", True)
    mitsuba.set_variant("scalar_rgb")
    table, markdown = [], []
    for model, configs, runs in (
        ("roughdielectric", ALL_DIELECTRIC_CONFIGS,
         (run_dielectric_eval_pdf, run_dielectric_sample)),
        ("roughconductor", ALL_CONDUCTOR_CONFIGS, (run_conductor_eval_pdf, run_conductor_sample)),
    ):
        for c in configs:
            rows = [r for run in runs for r in run(mitsuba, c)]
            table += rows
            markdown.append(_markdown_row(model, c, rows))
    if "--markdown" in sys.argv:
        print("\n".join(markdown))
    else:
        _print_table(table)
