"""Walter et al. 2007 section 6.1 / Fig. 12: the empirical microfacet distribution points of a
fit (``diagnostics.empirical_D``) against the fitted distribution and the other distributions,
each with the α that best matches the points."""

from __future__ import annotations

import functools

import numpy as np

from fitlab._jax import jax, jnp
from fitlab.microfacet import DISTRIBUTIONS
from fitlab.report.style import new_figure, styled

#: α grid for matching each distribution to the points (log-spaced, fine enough for 3 digits).
ALPHA_GRID = np.geomspace(1e-3, 1.0, 1201)
#: |log ratio| is capped here (a factor of 100) when matching and reporting: a distribution that
#: is 0 at a point, e.g. Beckmann's underflowing tail, would otherwise count as infinitely wrong
#: and decide the match alone.
LOG_RATIO_CAP = float(np.log(100.0))


@functools.lru_cache(maxsize=None)
def _D_jitted(distribution: str):
    return jax.jit(DISTRIBUTIONS[distribution].D)


def D_curve(distribution: str, alpha, theta_m_deg) -> np.ndarray:
    """D(m) (1/sr) of a named distribution for microfacet normals at θm (degrees, in a plane)."""
    t = np.radians(np.asarray(theta_m_deg, float))
    m = np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], axis=-1)
    return np.asarray(_D_jitted(distribution)(jnp.asarray(m),
                                               jnp.asarray(alpha, dtype=jnp.asarray(m).dtype)))


def best_alpha(distribution: str, theta_m_deg, D_points) -> tuple[float, float]:
    """(α, RMS log ratio): the α on ALPHA_GRID whose D best matches the points in log space."""
    th, D = np.asarray(theta_m_deg, float), np.asarray(D_points, float)

    def rms_of(alphas):
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.log(D[None, :] / D_curve(distribution, alphas[:, None], th[None, :]))
        r = np.clip(np.where(np.isnan(r), LOG_RATIO_CAP, r), -LOG_RATIO_CAP, LOG_RATIO_CAP)
        return np.sqrt(np.mean(r**2, axis=1))

    rms = rms_of(ALPHA_GRID)
    k = int(np.argmin(rms))
    # Golden-section search in log α between the grid neighbours of the best grid point.
    lo, hi = np.log(ALPHA_GRID[max(k - 1, 0)]), np.log(ALPHA_GRID[min(k + 1, ALPHA_GRID.size - 1)])
    g = (np.sqrt(5.0) - 1.0) / 2.0
    for _ in range(40):
        a, b = hi - g * (hi - lo), lo + g * (hi - lo)
        ra, rb = rms_of(np.exp(np.array([a, b])))
        lo, hi = (lo, b) if ra <= rb else (a, hi)
    best = float(np.exp(0.5 * (lo + hi)))
    r_best = float(rms_of(np.array([best]))[0])
    return (best, r_best) if r_best <= rms[k] else (float(ALPHA_GRID[k]), float(rms[k]))


def distribution_curves(theta_m_deg, D_points, fitted_distribution: str, fitted_alpha: float):
    """[(label, θm grid, D, rms log ratio)]: the fit's own distribution at its fitted α first,
    then every distinct distribution of the registry matched to the points."""
    grid = np.linspace(0.0, min(89.0, max(60.0, float(np.max(theta_m_deg)) + 5.0)), 241)
    D_fit = D_curve(fitted_distribution, fitted_alpha, theta_m_deg)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.log(np.asarray(D_points) / D_fit)
    r = np.clip(np.where(np.isnan(r), LOG_RATIO_CAP, r), -LOG_RATIO_CAP, LOG_RATIO_CAP)
    rms_fit = float(np.sqrt(np.mean(r**2)))
    out = [(f"{fitted_distribution}, fitted α = {fitted_alpha:.4g} (the BSDF fit)", grid,
            D_curve(fitted_distribution, fitted_alpha, grid), rms_fit)]
    seen = set()
    for name, dist in DISTRIBUTIONS.items():
        if dist.D in seen:
            continue  # beckmann_rational shares Beckmann's D
        seen.add(dist.D)
        a, rms = best_alpha(name, theta_m_deg, D_points)
        out.append((f"{name}, α = {a:.4g} matched to the points", grid, D_curve(name, a, grid),
                    rms))
    return out


@styled
def empirical_D_figure(theta_m_deg, D_points, curves):
    """Empirical D points and distribution curves, log D against θm. Returns a Figure."""
    fig = new_figure(6.4, 4.2)
    ax = fig.add_subplot()
    ax.semilogy(theta_m_deg, D_points, "o", ms=3.2, color="k", label="empirical D (data, G = 1)")
    styles = ["-", "--", "-.", ":"]
    for k, (label, th, D, rms) in enumerate(curves):
        ax.semilogy(th, D, styles[k % 4], lw=1.5 if k == 0 else 1.1,
                    label=f"{label}; RMS log ratio {rms:.3f}")
    pts = np.asarray(D_points)
    ax.set_ylim(pts.min() * 0.3, pts.max() * 3.0)
    ax.set_xlabel("microfacet normal angle θm (°)")
    ax.set_ylabel("D(m) (1/sr)")
    ax.set_title("Walter 2007 §6.1: empirical microfacet distribution")
    ax.legend(loc="lower left", frameon=False, fontsize=7.2)
    return fig
