"""Microfacet albedo by quadrature (Walter eq. 41 weights over warped normals): the integrals
behind the albedo_conductor, dfg and albedo_dielectric tables.

Deterministic quadrature (``fitlab.quadrature``), never Monte Carlo: over the microfacet normal in
the warped coordinates of the distribution's sampling (Walter eqs 28 / 35), where the integrand is
Walter's sample weight (eq. 41), with Gauss–Legendre panels (smoothed ends) in θm and φm split at
the analytic breakpoints (horizon of the reflected / refracted direction, facet facing away, total
internal reflection, and where these appear in φm). Fresnel and refraction come from one
:func:`fitlab.fresnel.fresnel_dielectric` per normal.
"""

from __future__ import annotations

import functools

import numpy as np

from fitlab._jax import jax, jnp
from fitlab.frame import reflect, refracted
from fitlab.fresnel import cos_theta_critical, fresnel_dielectric
from fitlab.lut.axes import MU_MIN
from fitlab.microfacet import DISTRIBUTIONS, get_distribution
from fitlab.numerics import ALPHA_MIN
from fitlab.quadrature import gauss_legendre, gauss_legendre_panels


#: The registry's distributions the albedo quadrature supports, in registry order.
ALBEDO_DISTRIBUTIONS = tuple(name for name, d in DISTRIBUTIONS.items() if d.du1_dt is not None)

#: Default quadrature orders: Gauss–Legendre nodes per θm panel (in t), per φm panel (over
#: [0, π]) and in μ for the averages; the error estimate compares these with twice these, whose
#: values are stored.
QUAD_ORDERS = {"n_u": 8, "n_phi": 4, "n_mu": 16}
#: Panels are graded towards each horizon breakpoint at these multiples of α (the width over
#: which Smith's G1(o) falls to 0 as the outgoing direction reaches the horizon).
_GRADING = (2.0, 0.5, 0.125)


def _breakpoints(ci, eta, phi, transmission: bool):
    """θm breakpoints in [0, π/2] at fixed φm for incidence wi = (sin θi, 0, cos θi):
    horizon of the reflected direction, and (with transmission) facing, total internal
    reflection and horizon of the refracted direction. Shape (..., K), unsorted."""
    half_pi = 0.5 * jnp.pi
    si = jnp.sqrt(jnp.maximum(1.0 - ci * ci, 0.0))
    cp, sp = jnp.cos(phi), jnp.sin(phi)
    # o_r.z = 2(i·m) cos θm - cos θi = 0  <=>  tan 2θm = -cos θi / (sin θi cos φm)
    theta_r = 0.5 * jnp.arctan2(ci, -si * cp)
    if not transmission:
        return theta_r[..., None]
    # i·m = A cos(θm - θ0): facing boundary θ0 + π/2, TIR boundaries θ0 ± acos(c_crit / A)
    A = jnp.sqrt(ci * ci + (si * cp) ** 2)
    theta0 = jnp.arctan2(si * cp, ci)
    theta_c = theta0 + half_pi
    c_crit = cos_theta_critical(eta)
    has_tir = (eta < 1.0) & (c_crit < A)
    delta = jnp.arccos(jnp.clip(c_crit / jnp.where(A > 0, A, 1.0), -1.0, 1.0))
    t1 = jnp.where(has_tir, theta0 - delta, 0.0)
    t2 = jnp.where(has_tir, theta0 + delta, 0.0)
    # o_t.z = 0: the generalized half-vector (Walter eq. 16) wi + η wo with wo horizontal lies on
    # the circle (sin θi, 0) + η (cos ψ, sin ψ); along φm it is at tan θm = ρ / cos θi with
    # ρ² - 2ρ sin θi cos φm + sin²θi - η² = 0.
    disc = eta * eta - (si * sp) ** 2
    root = jnp.sqrt(jnp.maximum(disc, 0.0))
    rho_p, rho_m = si * cp + root, si * cp - root
    t3 = jnp.where((disc >= 0) & (rho_p > 0), jnp.arctan2(rho_p, ci), 0.0)
    t4 = jnp.where((disc >= 0) & (rho_m > 0), jnp.arctan2(rho_m, ci), 0.0)
    return jnp.stack([theta_r, theta_c, t1, t2, t3, t4], axis=-1)


def _phi_breakpoints(ci, alpha, eta, transmission: bool):
    """φm in [0, π] where the θm-breakpoint structure of :func:`_breakpoints` changes: φ = π/2
    (the reflection horizon and the facing boundary sweep across θm for grazing incidence) and,
    for η < 1, where total internal reflection starts (A = c_crit), where it reaches the
    horizon (sin θi cos φ = c_crit) and where the refracted horizon appears (η = sin θi sin φ)."""
    half_pi = 0.5 * jnp.pi
    out = [jnp.zeros_like(ci), jnp.full_like(ci, half_pi), jnp.full_like(ci, jnp.pi)]
    # near grazing incidence the reflection horizon θ_r(φ) drops from ~π/2 to 0 across
    # |φ - π/2| ~ cos θi; the integrand follows over ~ cos θi + α: grade towards π/2
    s = ci + alpha
    out += [jnp.clip(half_pi + sign * f * s, 0.0, jnp.pi) for f in (2.0, 0.5, 0.125)
            for sign in (-1.0, 1.0)]
    if transmission:
        si = jnp.sqrt(jnp.maximum(1.0 - ci * ci, 0.0))
        inv_si = 1.0 / jnp.maximum(si, 1e-300)
        c_crit = cos_theta_critical(eta)
        c1 = jnp.sqrt(jnp.maximum(c_crit**2 - ci * ci, 0.0)) * inv_si
        c2 = c_crit * inv_si
        s3 = eta * inv_si
        for v in (c1, -c1, c2):
            out.append(jnp.where((eta < 1.0) & (jnp.abs(v) <= 1.0), jnp.arccos(jnp.clip(v, -1, 1)), 0.0))
        a3 = jnp.arcsin(jnp.clip(s3, -1.0, 1.0))
        out += [jnp.where(s3 <= 1.0, a3, 0.0), jnp.where(s3 <= 1.0, jnp.pi - a3, 0.0)]
    return jnp.sort(jnp.stack(out))


def _albedo_point(mu, alpha, eta, *, distribution, mode, n_u, n_phi):
    """Albedo integrals at one (μ, α, η) by quadrature over microfacet normals.

    E = ∫∫ w(m) du1 du2 over the sampling's uniforms (Walter eqs 24, 28, 35), w being the
    sample weight of Walter eq. 41; u1 is changed to t (tan θm = α tan t), φm = 2π u2 over
    [0, π] (the integrand is even in φm). Both directions use Gauss–Legendre panels between
    breakpoints, with smoothed ends (``gauss_legendre_panels``); ``n_phi`` counts the nodes per
    φ panel. mode "conductor": [E] with F = 1; "dfg": [scale, bias]; "dielectric": [R, T] for
    incidence from the side where the relative index is η (rough_dielectric's frame flip)."""
    dist = get_distribution(distribution)
    du_dt = dist.du1_dt  # quadrature in t, tan θm = α tan t
    half_pi = 0.5 * jnp.pi
    ci = jnp.maximum(mu, MU_MIN)
    si = jnp.sqrt(jnp.maximum(1.0 - ci * ci, 0.0))
    wi = jnp.stack([si, jnp.zeros_like(si), ci])
    transmission = mode == "dielectric"
    phi, w_phi = gauss_legendre_panels(_phi_breakpoints(ci, alpha, eta, transmission), n_phi,
                                       smooth_ends=True, xp=jnp)
    w_phi = w_phi / jnp.pi  # ∫ du2 over [0, 1] = 2 ∫_0^π dφ / 2π
    br = _breakpoints(ci, eta, phi, transmission)
    horizons = br[..., :1] if not transmission else br[..., jnp.array([0, 4, 5])]
    g = alpha * jnp.asarray(_GRADING)
    graded = horizons[..., :, None] - g if not transmission else jnp.concatenate(
        [horizons[..., :, None] - g, horizons[..., :, None] + g], axis=-1)
    ends = jnp.broadcast_to(jnp.array([0.0, half_pi]), phi.shape + (2,))
    if transmission:
        theta_b = jnp.concatenate([ends, br, graded.reshape(phi.shape + (-1,))], axis=-1)
    else:  # reflection is valid on [0, θ_r] only
        theta_b = jnp.minimum(jnp.concatenate([ends[..., :1], br, graded.reshape(phi.shape + (-1,))],
                                              axis=-1), br[..., :1])
    theta_b = jnp.sort(jnp.clip(theta_b, 0.0, half_pi), axis=-1)
    # θm -> t: tan t = tan θm / α
    t_b = jnp.arctan2(jnp.sin(theta_b), alpha * jnp.cos(theta_b))
    t, w1 = gauss_legendre_panels(t_b, n_u, smooth_ends=True, xp=jnp)
    w1 = w1 * du_dt(t)
    sin_t, cos_t = jnp.sin(t), jnp.cos(t)
    r = jax.lax.rsqrt(cos_t * cos_t + (alpha * sin_t) ** 2)  # tan θm = α tan t
    st, ct = alpha * sin_t * r, cos_t * r
    cp = jnp.cos(phi)[:, None]
    m = jnp.stack([st * cp, st * jnp.sin(phi)[:, None], ct], axis=-1)
    c = m @ wi  # i·m
    mz = m[..., 2]
    # Walter eq. 41 without G1(o): |i·m| G1(i) / (|i·n| |m·n|); G1(i)/cos θi stays finite as μ → 0
    base = jnp.where((c > 0) & (mz > 0), c * dist.G1(wi, alpha) / (ci * jnp.where(mz > 0, mz, 1.0)), 0.0)
    W = w1 * w_phi[:, None]
    o_r = reflect(jnp.broadcast_to(wi, m.shape), m)  # Walter eq. 39
    ok_r = o_r[..., 2] > 0
    g_r = jnp.where(ok_r, dist.G1(o_r, alpha), 0.0) * base
    if mode == "conductor":
        return jnp.stack([jnp.sum(W * g_r)])
    if mode == "dfg":
        fc = (1.0 - c) ** 5  # Schlick: F = F0 + (1 - F0)(1 - v·h)^5 (Karis 2013)
        return jnp.stack([jnp.sum(W * g_r * (1.0 - fc)), jnp.sum(W * g_r * fc)])
    # Walter eq. 22 and Snell's law in one: F, cos θt and η_i/η_t at |i·m| (back-facing m have
    # base = 0)
    F, cos_theta_t, _, eta_ti = fresnel_dielectric(jnp.abs(c), jnp.broadcast_to(eta, c.shape))
    o_t = refracted(jnp.broadcast_to(wi, m.shape), m, cos_theta_t, eta_ti)  # Walter eq. 40
    ok_t = (cos_theta_t < 0) & (o_t[..., 2] < 0)  # cos θt = 0: total internal reflection
    g_t = jnp.where(ok_t, dist.G1(o_t, alpha), 0.0) * base
    return jnp.stack([jnp.sum(W * F * g_r), jnp.sum(W * (1.0 - F) * g_t)])


@functools.lru_cache(maxsize=None)
def _albedo_kernel(distribution, mode, n_u, n_phi):
    point = functools.partial(_albedo_point, distribution=distribution, mode=mode, n_u=n_u,
                              n_phi=n_phi)

    @jax.jit
    def run(mu, alpha, eta):
        return jax.lax.map(lambda a: point(*a), (mu, alpha, eta), batch_size=256)

    return run


def albedo_integrals(mu, alpha, eta=None, *, distribution="ggx", mode="conductor",
                     n_u=None, n_phi=None):
    """Albedo integrals at points (μ, α[, η]) (1D arrays) → (P, K) float64.

    mode "conductor": E with F = 1; "dfg": (scale, bias); "dielectric": (R, T) with relative
    index η = η_o / η_i of the incident side. Quadrature orders default to twice
    :data:`QUAD_ORDERS` (the orders of the stored values)."""
    if distribution not in ALBEDO_DISTRIBUTIONS:
        raise ValueError(f"albedo tables support the distributions "
                         f"{', '.join(ALBEDO_DISTRIBUTIONS)}, not {distribution!r}")
    n_u = n_u or 2 * QUAD_ORDERS["n_u"]
    n_phi = n_phi or 2 * QUAD_ORDERS["n_phi"]
    mu = jnp.asarray(mu, dtype=jnp.float64).ravel()
    alpha = jnp.maximum(jnp.asarray(alpha, dtype=jnp.float64).ravel(), ALPHA_MIN)
    eta = jnp.ones_like(mu) if eta is None else jnp.asarray(eta, dtype=jnp.float64).ravel()
    mu, alpha, eta = jnp.broadcast_arrays(mu, alpha, eta)
    # pad to a power of two (at least 64) so that few array shapes are ever compiled
    n = mu.shape[0]
    size = max(64, 1 << max(n - 1, 0).bit_length())
    pad = lambda x: jnp.concatenate([x, jnp.full(size - n, 0.5, dtype=x.dtype)])  # noqa: E731
    run = _albedo_kernel(distribution, mode, int(n_u), int(n_phi))
    return np.asarray(run(pad(mu), pad(alpha), pad(eta)))[:n]


def albedo_with_error(mu, alpha, eta, distribution, mode, orders):
    """Albedo integrals at the orders 2·``orders`` (stored) and their error estimate, the
    difference to the orders ``orders``."""
    lo = albedo_integrals(mu, alpha, eta, distribution=distribution, mode=mode,
                          n_u=orders["n_u"], n_phi=orders["n_phi"])
    hi = albedo_integrals(mu, alpha, eta, distribution=distribution, mode=mode,
                          n_u=2 * orders["n_u"], n_phi=2 * orders["n_phi"])
    return hi, np.abs(hi - lo)


def average_over_mu(alpha, eta, distribution, mode, orders):
    """E_avg = 2 ∫ E(μ) μ dμ (Gauss–Legendre in μ at n_mu and 2 n_mu nodes), with the error
    estimate |Q_n - Q_2n| + the largest error estimate of the E values used."""
    alpha = np.asarray(alpha, float).ravel()
    eta = np.ones_like(alpha) if eta is None else np.asarray(eta, float).ravel()
    # E_avg depends on (α, η) only: integrate once per distinct pair
    pairs, inverse = np.unique(np.stack([alpha, eta], axis=-1), axis=0, return_inverse=True)
    if len(pairs) < len(alpha):
        avg, err = average_over_mu(pairs[:, 0], pairs[:, 1], distribution, mode, orders)
        return avg[inverse.ravel()], err[inverse.ravel()]
    out, err = [], []
    for n in (orders["n_mu"], 2 * orders["n_mu"]):
        x, w = gauss_legendre(n, 0.0, 1.0)
        MU = np.broadcast_to(x, (alpha.size, n)).ravel()
        A = np.repeat(alpha, n)
        H = np.repeat(eta, n)
        E, dE = albedo_with_error(MU, A, H, distribution, mode, orders)
        E = E.reshape(alpha.size, n, -1)
        dE = dE.reshape(alpha.size, n, -1)
        out.append(2.0 * np.einsum("pnk,n->pk", E, w * x))
        err.append(dE.max(axis=1))
    return out[1], np.abs(out[1] - out[0]) + err[1]

