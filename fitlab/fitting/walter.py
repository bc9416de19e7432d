"""Walter et al. 2007 section 6.1: empirical microfacet distribution points from measured data.

Far from grazing (|i·n| > 0.5 and |o·n| > 0.5) G ≈ 1, so eq. 21 (transmission) or eq. 20
(reflection) can be solved for D(h) at each measured pair. Points with very low measured values
(below 1% of the maximum) are left out, as Walter did, since stray light dominates them. If the
data follow a microfacet model, the points lie on the fitted D.
"""

from __future__ import annotations

import numpy as np

from fitlab._jax import jnp
from fitlab.fresnel import DIELECTRIC_FRESNEL_METHODS
from fitlab.frame import dot, flip_z, half_vector_transmission, normalize
from fitlab.io.fitfile import fit_parameters

COS_MIN = 0.5
LOW_VALUE = 0.01


def empirical_D(wi, wo, value, eta, scale=1.0, fresnel="exact"):
    """(θm in degrees, D_empirical, mask) for a rough dielectric with relative index ``eta``.

    ``value`` is the measured f (or f times ``scale`` for relative data); ``fresnel`` names the
    fitted model's F in ``DIELECTRIC_FRESNEL_METHODS`` (Walter eq. 22 by default)."""
    wi, wo = jnp.asarray(wi), jnp.asarray(wo)
    s = jnp.where(wi[..., 2] < 0, -1.0, 1.0)
    wi, wo = flip_z(wi, s), flip_z(wo, s)
    eta = jnp.where(s > 0, eta, 1.0 / eta)
    is_r = wo[..., 2] > 0
    h = jnp.where(is_r[..., None], wi + wo, half_vector_transmission(wi, wo, eta))
    hh = normalize(h)
    i_h, o_h = dot(wi, hh), dot(wo, hh)
    F = DIELECTRIC_FRESNEL_METHODS[fresnel](i_h, eta)
    ci, co = wi[..., 2], jnp.abs(wo[..., 2])
    # f = K · G · D with G := 1: K from eq. 20 (reflection) or eq. 21 (transmission).
    K_r = F / (4.0 * ci * co)
    K_t = jnp.abs(i_h * o_h) * eta**2 * (1.0 - F) / (ci * co * dot(h, h))
    K = np.asarray(jnp.where(is_r, K_r, K_t))
    v = np.asarray(value) / scale
    ok = (np.asarray(ci) > COS_MIN) & (np.asarray(co) > COS_MIN) & (K > 0) \
        & (np.asarray(i_h) > 0) & (np.asarray(o_h * jnp.where(is_r, 1.0, -1.0)) > 0)
    ok &= np.asarray(value) >= LOW_VALUE * np.max(np.abs(value))
    theta_m = np.degrees(np.arccos(np.clip(np.asarray(hh[..., 2]), -1, 1)))
    D = np.where(ok, v / np.where(K > 0, K, 1.0), np.nan)
    return theta_m, D, ok, np.asarray(hh)


def applies_to(model) -> bool:
    """Walter's diagnostic solves eq. 20/21 of one rough dielectric interface for D: the model
    must declare a microfacet distribution, transmission, and a single index parameter."""
    return (model.microfacet is not None and model.capabilities.transmission
            and len(model.parameters_with_role("index")) == 1)


def add_empirical_D(record, result, m):
    """Add the empirical D points and their agreement with the fitted D to the record."""
    model = result["model"]
    fitted = fit_parameters(record)  # {channel: {parameter: value}}, scale included
    for fit, ch in zip(record["fits"], result["channels"]):
        if not applies_to(model):
            fit["diagnostics"] = {"empirical_D": {
                "skipped": "only for a single rough dielectric interface (a model with a "
                           "microfacet distribution, transmission and one index parameter)"}}
            continue
        params = fitted[fit["channel"]]
        scale = params.get("scale", 1.0)
        rows = ch["rows"]
        eta = params[model.parameters_with_role("index")[0].name]
        fresnel = result["options"].get("fresnel", "exact")
        theta_m, D, ok, hh = empirical_D(
            m.wi[rows], m.wo[rows], m.value[rows], eta, scale,
            fresnel if fresnel in DIELECTRIC_FRESNEL_METHODS else "exact")
        dist = model.microfacet(params, **result["options"])
        D_fit = np.asarray(dist.D(jnp.asarray(hh)))
        log_ratio = np.log(D[ok] / D_fit[ok]) if ok.any() else np.array([])
        fit["diagnostics"] = {"empirical_D": {
            "method": "Walter 2007 section 6.1: |i·n| > 0.5, |o·n| > 0.5, G = 1, values >= 1% "
                      "of the maximum; eq. 20/21 solved for D",
            "points": int(ok.sum()),
            "theta_m_deg": [float(x) for x in theta_m[ok]],
            "D_empirical": [float(x) for x in D[ok]],
            "D_fitted": [float(x) for x in D_fit[ok]],
            "rms_log_ratio": float(np.sqrt(np.mean(log_ratio**2))) if log_ratio.size else None,
        }}
