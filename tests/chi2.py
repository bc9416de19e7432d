"""Pearson χ² goodness-of-fit test of a direction sampler against its claimed density.

After Mitsuba 3's ``mitsuba/python/chi2.py`` (``ChiSquareTest`` with ``SphericalDomain``): draw
many samples, histogram the valid ones over a grid on the whole sphere, integrate the claimed pdf
over every cell to get expected counts, pool cells whose expectation is below 5, and compare the
statistic with the χ² distribution. Differences from Mitsuba, all to keep the test exact for
the narrow lobes of smooth microfacet surfaces:

* The grid is in (θ, φ), θ in [0, π] from +z, φ in [-π, π]. Its edges are the union of uniform
  edges (for the tails) and quantiles of an independent *pilot* batch of samples (for power
  inside narrow lobes); θ = π/2 is always an edge, so the horizon discontinuity of a BSDF never
  falls inside a cell. The pilot batch is independent of the tested batch, so under the null
  hypothesis the counts are still multinomial with the integrated cell probabilities.
* The pdf is integrated over each cell with adaptive tensor Gauss–Legendre quadrature (a cell is
  split into four until the 4-child estimate agrees with the parent's), not a fixed trapezoid.
* Invalid samples (pdf 0: absorbed, below the horizon, ...) form one more category, with the
  expected count N (1 - ∫pdf). The test therefore also checks that the pdf's mass equals the
  fraction of valid samples.
* Mitsuba rejects samples that land in cells of zero expected count; here the pdf is evaluated
  at every valid sample and must be positive there (exact, whereas a cell's quadrature can miss
  a thin sliver of support at the edge of a lobe).

Everything runs in float64 with fixed seeds, so results are deterministic.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import stats

#: Cells with a smaller expected count are pooled (as in Mitsuba, after Cochran's rule).
POOL_THRESHOLD = 5.0


def sidak_level(significance: float, n_tests: int) -> float:
    """Per-test level at which ``n_tests`` independent tests reject together with probability
    ``significance``: 1 - (1 - significance)^(1/n_tests)."""
    return 1.0 - (1.0 - significance) ** (1.0 / n_tests)


def sidak_z(significance: float, n_tests: int) -> float:
    """Two-sided normal quantile at the Šidák-corrected level."""
    return float(stats.norm.isf(0.5 * sidak_level(significance, n_tests)))


def spherical_directions(theta, phi):
    """Unit vectors (..., 3) for θ from +z and φ from +x."""
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


def to_spherical(w):
    w = np.asarray(w, dtype=np.float64)
    theta = np.arctan2(np.hypot(w[..., 0], w[..., 1]), w[..., 2])
    phi = np.arctan2(w[..., 1], w[..., 0])
    return theta, phi


# ----------------------------------------------------------------------------------------------
# Grid
# ----------------------------------------------------------------------------------------------


def _merge_edges(lo, hi, uniform, quantiles, fixed=(), min_width=1e-7):
    """Sorted edges from lo to hi: uniform divisions, quantiles and fixed edges, without slivers."""
    edges = np.concatenate([np.linspace(lo, hi, uniform + 1), np.asarray(quantiles, float)])
    edges = np.unique(np.clip(edges, lo, hi))
    keep = [lo]
    for e in edges[1:-1]:
        if e - keep[-1] >= min_width and hi - e >= min_width:
            keep.append(e)
    return np.unique(np.concatenate([keep, [hi], np.asarray(fixed, float)]))


def grid_edges(pilot_wo, n_uniform_theta=16, n_uniform_phi=16, n_quantile=32, fixed_theta=()):
    """θ and φ edges from uniform divisions plus quantiles of a pilot batch of valid samples;
    θ = π/2 and ``fixed_theta`` (cones where the density is known to jump) are always edges."""
    levels = (np.arange(1, n_quantile) / n_quantile)
    if len(pilot_wo):
        theta, phi = to_spherical(pilot_wo)
        qt, qp = np.quantile(theta, levels), np.quantile(phi, levels)
    else:
        qt = qp = np.empty(0)
    theta_edges = _merge_edges(0.0, np.pi, n_uniform_theta, qt, fixed=(0.5 * np.pi, *fixed_theta))
    phi_edges = _merge_edges(-np.pi, np.pi, n_uniform_phi, qp)
    return theta_edges, phi_edges


def histogram(wo, theta_edges, phi_edges):
    """Counts (nθ, nφ) of directions; the hemisphere of a direction decides its side of θ = π/2
    even where rounding would put θ exactly on the horizon."""
    wo = np.asarray(wo, dtype=np.float64)
    theta, phi = to_spherical(wo)
    nt, nphi = len(theta_edges) - 1, len(phi_edges) - 1
    it = np.clip(np.searchsorted(theta_edges, theta, side="right") - 1, 0, nt - 1)
    horizon = int(np.flatnonzero(theta_edges == 0.5 * np.pi)[0])  # first lower-hemisphere row
    it = np.where(wo[:, 2] > 0, np.minimum(it, horizon - 1), it)
    it = np.where(wo[:, 2] < 0, np.maximum(it, horizon), it)
    ip = np.clip(np.searchsorted(phi_edges, phi, side="right") - 1, 0, nphi - 1)
    return np.bincount(it * nphi + ip, minlength=nt * nphi).reshape(nt, nphi).astype(np.float64)


# ----------------------------------------------------------------------------------------------
# Adaptive Gauss–Legendre integration of the pdf over the cells
# ----------------------------------------------------------------------------------------------


def _gl_cells(density, cells, nodes, weights):
    """Tensor Gauss–Legendre estimate of ∫∫ density(θ, φ) sinθ dθ dφ over each cell (n, 4)."""
    t0, t1, p0, p1 = cells.T
    ht, hp = 0.5 * (t1 - t0), 0.5 * (p1 - p0)
    theta = (0.5 * (t0 + t1))[:, None, None] + ht[:, None, None] * nodes[None, :, None]
    phi = (0.5 * (p0 + p1))[:, None, None] + hp[:, None, None] * nodes[None, None, :]
    theta, phi = np.broadcast_arrays(theta, phi)
    f = density(spherical_directions(theta, phi).reshape(-1, 3)).reshape(theta.shape)
    f = f * np.sin(theta)
    return np.einsum("nij,i,j->n", f, weights, weights) * ht * hp


def _split(cells):
    t0, t1, p0, p1 = cells.T
    tm, pm = 0.5 * (t0 + t1), 0.5 * (p0 + p1)
    kids = np.stack([
        np.stack([t0, tm, p0, pm], -1), np.stack([t0, tm, pm, p1], -1),
        np.stack([tm, t1, p0, pm], -1), np.stack([tm, t1, pm, p1], -1),
    ], axis=1)
    return kids.reshape(-1, 4)


def integrate_cells(density, theta_edges, phi_edges, order=5, rtol=1e-6, atol=1e-9,
                    max_depth=9):
    """Mass of ``density`` (vectorized over (n, 3) directions) in every cell, (nθ, nφ), and the
    summed error estimate of unconverged (max-depth) and converged cells."""
    nodes, weights = np.polynomial.legendre.leggauss(order)
    T0, P0 = np.meshgrid(theta_edges[:-1], phi_edges[:-1], indexing="ij")
    T1, P1 = np.meshgrid(theta_edges[1:], phi_edges[1:], indexing="ij")
    cells = np.stack([T0.ravel(), T1.ravel(), P0.ravel(), P1.ravel()], -1)
    n = len(cells)
    root = np.arange(n)
    coarse = _gl_cells(density, cells, nodes, weights)
    total, error = np.zeros(n), np.zeros(n)
    for depth in range(max_depth + 1):
        if not len(cells):
            break
        kids = _split(cells)
        kv = _gl_cells(density, kids, nodes, weights).reshape(-1, 4)
        fine = kv.sum(axis=1)
        err = np.abs(fine - coarse)
        done = (err <= np.maximum(rtol * np.abs(fine), atol)) | (depth == max_depth)
        np.add.at(total, root[done], fine[done])
        np.add.at(error, root[done], err[done])
        keep = ~done
        cells = kids.reshape(-1, 4, 4)[keep].reshape(-1, 4)
        coarse = kv[keep].reshape(-1)
        root = np.repeat(root[keep], 4)
    shape = (len(theta_edges) - 1, len(phi_edges) - 1)
    return total.reshape(shape), float(error.sum())


# ----------------------------------------------------------------------------------------------
# The statistic
# ----------------------------------------------------------------------------------------------


def pooled_chi2(observed, expected, pool_threshold=POOL_THRESHOLD):
    """Pearson statistic with Mitsuba's pooling: cells with expected count below the threshold
    are merged, in increasing order of expectation, into groups of at least the threshold (a last
    incomplete group joins the previous one). Returns (statistic, dof, cells pooled, groups)."""
    observed = np.asarray(observed, float).ravel()
    expected = np.asarray(expected, float).ravel()
    order = np.argsort(expected, kind="stable")
    observed, expected = observed[order], expected[order]
    high = expected >= pool_threshold
    obs_g, exp_g = list(observed[high]), list(expected[high])
    low = ~high & ((observed != 0) | (expected != 0))
    pooled_in = int(low.sum())
    groups_o, groups_e = [], []
    acc_o = acc_e = 0.0
    for o, e in zip(observed[low], expected[low]):
        acc_o += o
        acc_e += e
        if acc_e >= pool_threshold:
            groups_o.append(acc_o)
            groups_e.append(acc_e)
            acc_o = acc_e = 0.0
    if acc_e > 0 or acc_o > 0:
        if groups_e:
            groups_o[-1] += acc_o
            groups_e[-1] += acc_e
        elif obs_g:  # nothing reached the threshold: join the smallest regular cell
            obs_g[0] += acc_o
            exp_g[0] += acc_e
        else:
            groups_o.append(acc_o)
            groups_e.append(acc_e)
    o = np.asarray(obs_g + groups_o)
    e = np.asarray(exp_g + groups_e)
    stat = float(np.sum((o - e) ** 2 / e))
    return stat, len(e) - 1, pooled_in, len(groups_e)


@dataclasses.dataclass
class Chi2Result:
    p_value: float
    statistic: float
    dof: int
    n_samples: int
    valid_fraction: float
    pdf_mass: float
    quadrature_error: float
    n_cells: int
    messages: list[str]

    def mass_sigma(self) -> float:
        """Binomial standard deviation of the valid fraction (floored at one sample)."""
        p = min(max(self.pdf_mass, 1.0 / self.n_samples), 1.0 - 1.0 / self.n_samples)
        return float(np.sqrt(p * (1.0 - p) / self.n_samples))

    def report(self) -> str:
        return (f"p={self.p_value:.4g} chi2={self.statistic:.1f} dof={self.dof} "
                f"N={self.n_samples} valid={self.valid_fraction:.6f} mass={self.pdf_mass:.6f} "
                f"quad_err={self.quadrature_error:.2e} cells={self.n_cells}; "
                + "; ".join(self.messages))


def chi2_test(sample, density, n_samples, seed, n_pilot=10_000, **grid):
    """Run the test.

    ``sample(u)`` maps uniforms (n, 3) to ``(wo, pdf)`` numpy arrays, pdf 0 marking invalid
    samples; ``density(wo)`` is the claimed solid-angle pdf of valid samples.
    """
    rng = np.random.default_rng(seed)
    pilot_u = rng.random((n_pilot, 3))
    u = rng.random((n_samples, 3))
    pilot_wo, pilot_pdf = sample(pilot_u)
    theta_edges, phi_edges = grid_edges(pilot_wo[pilot_pdf > 0], **grid)

    wo, pdf = sample(u)
    valid = pdf > 0
    messages = []
    if not np.all(np.isfinite(wo[valid])):
        messages.append("non-finite sampled directions")
    counts = histogram(wo[valid], theta_edges, phi_edges)
    mass, qerr = integrate_cells(density, theta_edges, phi_edges)
    expected = mass * n_samples
    if np.any(mass < 0):
        messages.append(f"negative cell mass {mass.min():.3g}")
    # Mitsuba rejects samples in cells of zero expectation; checking the pdf at the samples
    # themselves is the exact form of that test (a cell's quadrature may miss a thin sliver).
    at_samples = density(wo[valid]) if valid.any() else np.empty(0)
    zero_hit = ~(at_samples > 0)
    if np.any(zero_hit):
        messages.append(f"{int(zero_hit.sum())} valid samples where the pdf is zero, e.g. "
                        f"{wo[valid][zero_hit][:3].tolist()}")
    total = float(mass.sum())
    obs = np.append(counts.ravel(), n_samples - valid.sum())
    exp = np.append(expected.ravel(), max(n_samples * (1.0 - total), 0.0))
    stat, dof, pooled_in, pooled_out = pooled_chi2(obs, exp)
    if pooled_in:
        messages.append(f"pooled {pooled_in} cells into {pooled_out}")
    if dof < 1:
        messages.append("too few degrees of freedom")
    p_value = float(stats.chi2.sf(stat, dof)) if dof >= 1 else float("nan")
    if np.any(zero_hit) or not np.all(np.isfinite(wo[valid])) or dof < 1:
        p_value = 0.0
    return Chi2Result(p_value, stat, dof, n_samples, float(valid.mean()), total, qerr,
                      counts.size, messages)
