"""Fresnel reflectance for unpolarized light.

Variants are named after their source and dispatched through :data:`FRESNEL_METHODS`
(colour-science style). ``cos_i`` is the cosine between the incident direction and the
(micro)surface normal on the incident side; signs are handled by the caller.
"""

from __future__ import annotations

from fitlab._jax import jnp
from fitlab.numerics import safe_div, safe_sqrt


def _walter_F_g(c, eta_it):
    """Walter eq. 22 for c = |cos θi| and the relative index η_t/η_i of the crossing: (F, g),
    g = η_t/η_i · |cos θt| = sqrt(η_t²/η_i² - 1 + c²) (0 under total internal reflection)."""
    g2 = eta_it**2 - 1.0 + c**2
    tir = g2 <= 0
    # double where (finite gradient under total internal reflection); a NaN stays NaN
    g = jnp.where(tir, 0.0, jnp.sqrt(jnp.where(tir, 1.0, g2)))
    # Walter eq. 22: F = 1/2 (g-c)²/(g+c)² (1 + (c(g+c)-1)² / (c(g-c)+1)²)
    a = safe_div(g - c, g + c)
    b = safe_div(c * (g + c) - 1.0, c * (g - c) + 1.0)
    return jnp.where(tir, 1.0, jnp.clip(0.5 * a**2 * (1.0 + b**2), 0.0, 1.0)), g


def fresnel_dielectric(cos_theta_i, eta):
    """Fresnel reflectance of a smooth dielectric interface and what a refraction through it
    needs, computed once (Mitsuba 3's ``fresnel(cos_theta_i, eta)``).

    ``eta`` = η_inside / η_outside, the index on the -normal side over the +normal side.
    ``cos_theta_i`` is the cosine between the incident direction (pointing away from the
    surface) and the normal; a negative value means incidence from inside, where the relative
    index of the crossing is 1/η. Returns ``(F, cos_theta_t, eta_it, eta_ti)``:

    - F: unpolarized reflectance, Walter eq. 22 ([CT82] form); 1 under total internal reflection
    - cos_theta_t: cosine of the transmitted direction (pointing away from the surface on the
      other side, so of the sign opposite to cos_theta_i); 0 under total internal reflection
    - eta_it = η_t / η_i and eta_ti = η_i / η_t of this crossing

    Snell's law in Walter's variable: g = η_t/η_i · cos θt = sqrt(η_t²/η_i² - 1 + cos²θi).
    Gradients are finite everywhere (double-where pattern); NaN inputs give NaN.
    """
    outside = cos_theta_i >= 0
    inv_eta = safe_div(1.0, eta)
    eta_it = jnp.where(outside, eta, inv_eta)
    eta_ti = jnp.where(outside, inv_eta, eta)
    F, g = _walter_F_g(jnp.abs(cos_theta_i), eta_it)
    # |cos θt| = g η_i/η_t (0 under total internal reflection, g = 0); the product can round
    # above 1 near normal incidence, where sqrt(1 - cos²θt) of a caller would be NaN
    cos_t = jnp.minimum(g * eta_ti, 1.0)
    return F, jnp.where(outside, -cos_t, cos_t), eta_it, eta_ti


def fresnel_dielectric_Walter2007(cos_i, eta):
    """Exact dielectric Fresnel reflectance, Walter eq. 22 ([CT82] form): the F of
    :func:`fresnel_dielectric` for incidence from the side of ``cos_i``'s normal.

    ``eta`` = η_t / η_i (transmitted over incident index); ``cos_i`` enters as |cos_i|. Total
    internal reflection (g² < 0) gives 1.
    """
    return _walter_F_g(jnp.abs(cos_i), eta)[0]  # no side selection: cos_i is the incident side


def cos_theta_critical(eta):
    """Cosine of the critical angle of incidence for the relative index ``eta`` = η_t / η_i:
    total internal reflection for cos θi < sqrt(1 - η²) (where g² of Walter eq. 22 is < 0);
    0 for η ≥ 1 (no total internal reflection)."""
    return safe_sqrt(1.0 - eta * eta)


def fresnel_conductor_exact(cos_i, n, k):
    """Exact Fresnel reflectance of a conductor with complex index n + i k relative to the
    incident medium (unpolarized average of the s and p reflectances; the closed form of
    pbrt-v3 ``FrConductor`` / Mitsuba ``fresnel_conductor``)."""
    c = jnp.clip(jnp.abs(cos_i), 0.0, 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    t0 = n * n - k * k - s2
    a2b2 = safe_sqrt(t0 * t0 + 4.0 * n * n * k * k)  # a² + b²
    # a² = (a2b2 + t0)/2, rationalized where t0 < 0 (a2b2 ≈ -t0 there: below the critical
    # angle of n < 1 with small k the sum cancels to rounding noise, and XLA's differently
    # rounded copies of it inside safe_sqrt's two where's once disagreed on its sign, giving
    # a = 1 and F = 0 instead of F = 1): (a2b2² - t0²) / (2 (a2b2 - t0)) = 2 n²k² / (a2b2 - t0)
    a2 = jnp.where(t0 >= 0, 0.5 * (a2b2 + t0), safe_div(2.0 * n * n * k * k, a2b2 - t0))
    a = safe_sqrt(a2)
    t1 = a2b2 + c2
    t2 = 2.0 * c * a
    Rs = safe_div(t1 - t2, t1 + t2, 1.0)
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    Rp = Rs * safe_div(t3 - t4, t3 + t4, 1.0)
    return jnp.clip(0.5 * (Rp + Rs), 0.0, 1.0)


def fresnel_schlick(cos_i, f0):
    """Schlick's approximation [Sch94]: F0 + (1 - F0)(1 - cos)^5."""
    q = 1.0 - jnp.clip(jnp.abs(cos_i), 0.0, 1.0)
    return f0 + (1.0 - f0) * q**5


#: Hoffman 2019's angle for the Lazányi–Szirmay-Kalos correction: μ̄ = cos θ = 1/7 (θ ≈ 81.8°),
#: where its shape μ(1 - μ)^6 peaks (OpenPBR's "F82").
LAZANYI_MU = 1.0 / 7.0


def fresnel_conductor_LazanyiSzirmayKalos(cos_i, n, k):
    """Lazányi & Szirmay-Kalos 2005 ("Fresnel term approximations for metals", WSCG short
    papers): Schlick with F0 from (n, k), minus their correction term for metals,
    F = F_Schlick(μ) - a μ (1 - μ)^α, with α = 6 and a fitted per material. fitlab fits a as
    Hoffman 2019 ("Fresnel equations considered harmful"; OpenPBR's F82 model, notation of
    Kutz 2021) does: the approximation equals the exact reflectance at μ̄ = 1/7 (θ ≈ 81.8°, the
    peak of μ(1 - μ)^6, near where a metal's reflectance dips below Schlick's),
    a = (F_Schlick(μ̄) - F_exact(μ̄; n, k)) / (μ̄ (1 - μ̄)^6). Exact at normal and grazing
    incidence (the term vanishes there) and at μ̄; clipped to [0, 1] (a < 0 when the exact
    reflectance at μ̄ lies above Schlick's, e.g. n < 1 with small k).

    Elek 2010 appendix B prints the form without the correction term,
    ((n-1)² + 4 n (1-μ)^5 + k²)/((n+1)² + k²), which is Schlick's with F0 from (n, k) to
    rounding: that is fitlab's ``schlick``. A renderer computes a once per material; this
    function derives it at every call (one exact Fresnel at μ̄), so its cost here is not the
    shader's."""
    q = 1.0 - jnp.clip(jnp.abs(cos_i), 0.0, 1.0)
    f0 = schlick_f0(n, k)
    mu = LAZANYI_MU
    w_bar = mu * (1.0 - mu) ** 6
    a = (fresnel_schlick(mu, f0) - fresnel_conductor_exact(mu, n, k)) / w_bar
    return jnp.clip(fresnel_schlick(cos_i, f0) - a * (1.0 - q) * q**6, 0.0, 1.0)


def schlick_f0(n, k=0.0):
    """Normal-incidence reflectance ((n-1)² + k²) / ((n+1)² + k²) used to drive Schlick."""
    return ((n - 1.0) ** 2 + k * k) / ((n + 1.0) ** 2 + k * k)


def fresnel_dielectric_Schlick(cos_i, eta):
    """Schlick's approximation [Sch94] of the dielectric reflectance, F0 = ((η-1)/(η+1))², for
    incidence from the side of ``cos_i``'s normal (``eta`` = η_t/η_i, the signature of
    :func:`fresnel_dielectric_Walter2007`).

    Schlick's polynomial is written for light arriving from the less dense medium. For light
    from the denser side (η_t/η_i < 1) it takes the cosine of the transmitted direction,
    |cos θt| = sqrt(1 - (1 - cos²θi)/η²) (Snell's law), the standard fix: the reflectance is then
    a function of the angle in the less dense medium, the same for a crossing and its reverse
    (so the BTDF keeps Walter eq. 21's generalized reciprocity), and 1 under total internal
    reflection (g² = η² - 1 + cos²θi ≤ 0, as in Walter eq. 22). Without it Schlick is wrong
    beyond the critical angle (below 1 where the exact F is 1). Gradients are finite
    (double-where); NaN inputs give NaN."""
    c = jnp.abs(cos_i)
    f0 = ((eta - 1.0) / (eta + 1.0)) ** 2
    g2 = eta**2 - 1.0 + c**2  # Walter eq. 22's g²: (η_t/η_i cos θt)²
    ok = g2 > 0
    cos_t = jnp.where(ok, jnp.sqrt(jnp.where(ok, g2, 1.0)), 0.0) * safe_div(1.0, eta)
    c_less_dense = jnp.where(eta >= 1.0, c, jnp.minimum(cos_t, 1.0))
    # total internal reflection: g² ≤ 0 (only for η < 1; at η = 1, c = 0 Schlick gives 1 too)
    return jnp.where(g2 <= 0, 1.0, fresnel_schlick(c_less_dense, f0))


#: Fresnel variants a dielectric model can use, by name; each takes (cos_i, eta = η_t/η_i).
DIELECTRIC_FRESNEL_METHODS = {
    "exact": fresnel_dielectric_Walter2007,
    "schlick": fresnel_dielectric_Schlick,
}

#: Fresnel variants a conductor model can use, by name. Each takes (cos_i, n, k).
CONDUCTOR_FRESNEL_METHODS = {
    "exact": fresnel_conductor_exact,
    "schlick": lambda cos_i, n, k: fresnel_schlick(cos_i, schlick_f0(n, k)),
    "lazanyi": fresnel_conductor_LazanyiSzirmayKalos,
}

#: Named (n, k) presets at (690, 550, 450) nm for R, G, B, from Elek 2010 appendix A.
CONDUCTOR_PRESETS = {
    "copper": {"n": (0.213, 1.04, 1.17), "k": (4.05, 2.59, 2.36)},
    "chromium": {"n": (3.84, 3.18, 1.99), "k": (4.37, 4.41, 4.22)},
    "cuprite": {"n": (2.83, 3.10, 3.06), "k": (0.083, 0.19, 0.6)},
}
