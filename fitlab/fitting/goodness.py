"""Goodness of fit: does the model describe the data, or only approximate it? Pure functions of
arrays (residuals, incidence labels, directions, posterior draws); the fitter calls them through
fitlab.fitting.resampling and the parameter file keeps their result as ``fits[k].goodness``
(data_formats/fit_json.md, *Goodness of fit*).

Three checks, each a p-value against :data:`P_FAIL`:

1. **Per-incidence residual level.** With the ``chi2`` loss (residuals in units of the data's
   σ): the overall χ² and each incidence's χ²/dof, dof apportioned pro rata, dof_k =
   n_k (1 − p/N). With the other losses (no absolute noise level: the noise scale s² = Σr²/dof
   is fitted): each incidence's *variance ratio* mean_k(r²)/s², tested with the F statistic
   of that incidence's mean square against the other incidences' (F test of equal variances).
   Across incidences the smallest p-value is Šidák-corrected, 1 − (1 − p_min)^K.
2. **Structured residuals: a Wald–Wolfowitz runs test** of the residual signs along the
   measurement's scans. Chosen over the lag-1 autocorrelation because it uses signs only: its
   null distribution (independent signs) holds for any noise distribution and any
   heteroscedasticity, which real BSDF residuals have in plenty (a peak's relative residuals
   differ from the floor's by decades), and one outlier cannot mask or fake it. A model that
   misses a lobe leaves long stretches of one sign (too few runs): the test is one-sided.
   Scans: rows of one incidence that share φo, ordered by θo; rows in no such scan of at least
   :data:`MIN_SCAN` rows (hemispherical grids about the specular pole, scattered directions)
   are ordered along a Hilbert curve over the projected outgoing direction (wo.x, wo.y), one
   curve per side, which keeps neighbours in the order neighbours on the sphere. Pooled over
   all scans (normal approximation with continuity correction) and per incidence (Šidák).
3. **Posterior predictive check** (with MCMC): replicated data drawn from the likelihood the
   sampler used (Gaussian residuals, σ = 1 for ``chi2``, else the sampled σ_r) at posterior
   draws θ_s; two discrepancies, the χ² Σ(r/σ)² and the worst incidence's mean (r/σ)². The
   p-value P(T(y_rep) ≥ T(y)) is averaged over the draws from the exact conditional tail
   probability (χ² distribution; for the worst incidence 1 − Π_k F_χ²(n_k t; n_k)), so tiny
   p-values are resolved without simulating replicas. With a sampled σ_r the χ² discrepancy
   cannot fail (σ_r absorbs the misfit); the worst-incidence one is the informative one.

A check *fails* when its p-value is below :data:`P_FAIL` = 0.001 (after the Šidák correction
where it covers several incidences): at most 0.1% false alarms per check for a model that does
describe the data (``tests/fitting/test_goodness.py`` checks the nominal rate).

The block bootstrap's summaries (:func:`bootstrap_summary`) live here too; its refits are in
fitlab.fitting.resampling.
"""

from __future__ import annotations

import numpy as np

#: A check fails below this p-value.
P_FAIL = 1e-3
#: Rows of one incidence sharing φo form a scan when there are at least this many.
MIN_SCAN = 3
#: Bits per axis of the Hilbert curve that orders rows in no scan.
HILBERT_BITS = 16
#: Posterior draws used by the predictive check.
PPC_DRAWS = 200


def _stats():
    from scipy import stats  # loaded only when a fit is assessed

    return stats


# ---- incidence blocks and scans ------------------------------------------------------------


def incidence_blocks(theta_i, phi_i):
    """(keys (K, 2) of distinct (θi, φi mod 360) in sorted order, block index of every row):
    the fitter's incidence directions (as ``statistics.per_incidence``)."""
    keys = np.stack([np.asarray(theta_i, float), np.mod(np.asarray(phi_i, float), 360.0)], 1)
    uniq, block = np.unique(keys, axis=0, return_inverse=True)
    return uniq, block.reshape(-1)


def hilbert_index(x, y, bits: int = HILBERT_BITS):
    """Position along a Hilbert curve of points (x, y) in [-1, 1]² (integers, vectorized; the
    classic xy → d conversion, one bit level at a time)."""
    n = 1 << bits
    xi = np.clip(np.floor((np.asarray(x, float) + 1) / 2 * n), 0, n - 1).astype(np.int64)
    yi = np.clip(np.floor((np.asarray(y, float) + 1) / 2 * n), 0, n - 1).astype(np.int64)
    d = np.zeros(xi.shape, np.int64)
    s = n >> 1
    while s > 0:
        rx = (xi & s) > 0
        ry = (yi & s) > 0
        d += s * s * ((3 * rx.astype(np.int64)) ^ ry.astype(np.int64))
        # Rotate the quadrant so that the curve's sub-curves join end to start.
        flip = ~ry & rx
        xi = np.where(flip, n - 1 - xi, xi)
        yi = np.where(flip, n - 1 - yi, yi)
        xi, yi = np.where(~ry, yi, xi), np.where(~ry, xi, yi)
        s >>= 1
    return d


def scan_groups(block, theta_o, phi_o, wo, min_scan: int = MIN_SCAN):
    """The orderings the runs test follows: a list of (block, row indices in order, kind), kind
    ``scan`` (one φo, by θo) or ``hilbert`` (the rest of an incidence's rows on one side, along
    a Hilbert curve over (wo.x, wo.y))."""
    block = np.asarray(block)
    theta_o = np.asarray(theta_o, float)
    phi_key = np.round(np.mod(np.asarray(phi_o, float), 360.0), 6)
    wo = np.asarray(wo, float)
    out = []
    for b in np.unique(block):
        idx = np.flatnonzero(block == b)
        rest = []
        for p in np.unique(phi_key[idx]):
            scan = idx[phi_key[idx] == p]
            if scan.size >= min_scan:
                out.append((int(b), scan[np.argsort(theta_o[scan], kind="stable")], "scan"))
            else:
                rest.append(scan)
        if rest:
            rest = np.sort(np.concatenate(rest))
            for side in (wo[rest, 2] >= 0, wo[rest, 2] < 0):
                r = rest[side]
                if r.size >= 2:
                    h = hilbert_index(wo[r, 0], wo[r, 1])
                    out.append((int(b), r[np.argsort(h, kind="stable")], "hilbert"))
    return out


# ---- the runs test -------------------------------------------------------------------------


def runs_counts(signs):
    """(runs, expected runs, variance) of one sequence of ±1 signs under independence
    (Wald–Wolfowitz); zeros are left out."""
    s = np.asarray(signs)
    s = s[s != 0]
    n1, n2 = int(np.sum(s > 0)), int(np.sum(s < 0))
    n = n1 + n2
    if n < 2 or n1 == 0 or n2 == 0:
        return (1 if n else 0), (1.0 if n else 0.0), 0.0
    runs = 1 + int(np.sum(s[1:] != s[:-1]))
    mean = 1.0 + 2.0 * n1 * n2 / n
    var = 2.0 * n1 * n2 * (2.0 * n1 * n2 - n) / (n * n * (n - 1.0))
    return runs, mean, var


def runs_test(residuals, groups):
    """The runs test pooled over ``groups`` (index arrays): {runs, expected_runs, z, p_value,
    rows}. One-sided: too few runs (stretches of one sign) is structure. p is None when the
    signs carry no information (fewer than 2 of either sign)."""
    r = np.sign(np.asarray(residuals, float))
    total, mean, var, rows = 0, 0.0, 0.0, 0
    for g in groups:
        k, m, v = runs_counts(r[g])
        total, mean, var, rows = total + k, mean + m, var + v, rows + int(np.sum(r[g] != 0))
    if var <= 0:
        return {"runs": total, "expected_runs": mean, "z": None, "p_value": None, "rows": rows}
    z = (total - mean + 0.5) / np.sqrt(var)  # + 0.5: continuity correction (lower tail)
    return {"runs": total, "expected_runs": mean, "z": float(z),
            "p_value": float(_stats().norm.cdf(z)), "rows": rows}


# ---- residual level per incidence ----------------------------------------------------------


def sidak(p_values):
    """The smallest of K p-values, Šidák-corrected for K tests: 1 − (1 − p_min)^K (None if
    there is none)."""
    p = [x for x in p_values if x is not None]
    if not p:
        return None
    return float(-np.expm1(len(p) * np.log1p(-min(min(p), 1.0 - 1e-16))))


def chi2_test(residuals, n_params: int):
    """χ² of residuals in σ units: {chi2, dof, chi2_per_dof, p_value} (upper tail)."""
    r = np.asarray(residuals, float)
    dof = max(r.size - n_params, 1)
    chi2 = float(r @ r)
    return {"chi2": chi2, "dof": dof, "chi2_per_dof": chi2 / dof,
            "p_value": float(_stats().chi2.sf(chi2, dof))}


def incidence_levels(residuals, block, n_params: int, absolute_noise: bool):
    """Per incidence block: {n, statistic, p_value}. With ``absolute_noise`` the statistic is
    χ²/dof with dof apportioned (n_k (1 − p/N)); otherwise the variance ratio mean_k(r²)/s²
    (s² = Σr²/(N − p)), its p-value from the F test of the block's mean square against the
    other blocks' (None with one block: nothing to compare)."""
    st = _stats()
    r = np.asarray(residuals, float)
    block = np.asarray(block)
    n_all = r.size
    shrink = max(1.0 - n_params / n_all, 1e-9)
    total = float(r @ r)
    s2 = total / max(n_all - n_params, 1)
    blocks = np.unique(block)
    out = []
    for b in blocks:
        rb = r[block == b]
        n = rb.size
        ss = float(rb @ rb)
        if absolute_noise:
            dof = n * shrink
            out.append({"block": int(b), "n": int(n), "statistic": ss / dof,
                        "p_value": float(st.chi2.sf(ss, dof))})
            continue
        ratio = (ss / n) / s2 if s2 > 0 else None
        p = None
        if len(blocks) > 1 and ratio is not None:
            d1, d2 = n * shrink, (n_all - n) * shrink
            rest = (total - ss) / d2
            p = float(st.f.sf((ss / d1) / rest, d1, d2)) if rest > 0 else 0.0
        out.append({"block": int(b), "n": int(n), "statistic": ratio, "p_value": p})
    return out


# ---- posterior predictive check ------------------------------------------------------------


def posterior_predictive(residuals, sigma, block):
    """Posterior predictive p-values from residuals at S posterior draws ((S, N), loss units)
    and each draw's noise scale σ_s ((S,); 1 for ``chi2``): {draws, chi2: {observed_mean,
    replicated_mean, p_value}, worst_incidence: {observed_mean, replicated_mean, p_value}}.
    The replicated discrepancies' distributions given θ_s are exact (see the module text)."""
    st = _stats()
    R = np.asarray(residuals, float)
    e2 = (R / np.asarray(sigma, float)[:, None]) ** 2
    S, N = e2.shape
    t_chi2 = e2.sum(axis=1)
    p_chi2 = st.chi2.sf(t_chi2, N)
    block = np.asarray(block)
    blocks = np.unique(block)
    n_k = np.array([np.sum(block == b) for b in blocks], float)
    means = np.stack([e2[:, block == b].mean(axis=1) for b in blocks], 1)  # (S, K)
    t_max = means.max(axis=1)
    # P(max_k χ²(n_k)/n_k ≥ t) = 1 − Π_k F(n_k t; n_k)
    log_cdf = st.chi2.logcdf(t_max[:, None] * n_k[None, :], n_k[None, :]).sum(axis=1)
    p_max = -np.expm1(log_cdf)
    # E[max_k χ²(n_k)/n_k] by quadrature of the survival function over t ≥ 0.
    t_grid = np.linspace(0.0, max(4.0, float(np.max(t_max)) * 1.5), 4001)
    sf_grid = -np.expm1(st.chi2.logcdf(t_grid[:, None] * n_k[None, :], n_k[None, :]).sum(1))
    rep_max = float(np.sum((sf_grid[1:] + sf_grid[:-1]) / 2) * (t_grid[1] - t_grid[0]))
    return {"draws": int(S),
            "chi2": {"observed_mean": float(t_chi2.mean()), "replicated_mean": float(N),
                     "p_value": float(p_chi2.mean())},
            "worst_incidence": {"observed_mean": float(t_max.mean()),
                                "replicated_mean": rep_max, "p_value": float(p_max.mean())}}


# ---- all checks together -------------------------------------------------------------------


def _fails(p):
    return p is not None and p < P_FAIL


def assess(residuals, *, block, keys, theta_o, phi_o, wo, n_params: int, absolute_noise: bool,
           predictive=None) -> dict:
    """Every check on a channel's fitted rows (residuals at the least-squares optimum, loss
    units; ``block`` indexes ``keys``, the (θi, φi) of each incidence); ``predictive`` the
    result of :func:`posterior_predictive` or None. Returns the ``goodness`` record
    (data_formats/fit_json.md)."""
    r = np.asarray(residuals, float)
    groups = scan_groups(block, theta_o, phi_o, wo)
    pooled = runs_test(r, [g for _, g, _ in groups])
    kinds = {k for _, _, k in groups}
    levels = incidence_levels(r, block, n_params, absolute_noise)
    per = []
    for lv in levels:
        b = lv["block"]
        rt = runs_test(r, [g for bb, g, _ in groups if bb == b])
        per.append({"theta_i": float(keys[b][0]), "phi_i": float(keys[b][1]), "n": lv["n"],
                    ("chi2_per_dof" if absolute_noise else "variance_ratio"): lv["statistic"],
                    "level_p_value": lv["p_value"], "runs": rt["runs"],
                    "expected_runs": rt["expected_runs"], "runs_p_value": rt["p_value"]})
    level_p = sidak([x["level_p_value"] for x in per])
    runs_p = sidak([x["runs_p_value"] for x in per])
    out = {
        "p_fail": P_FAIL,
        "noise": ("sigma: residuals in units of the data's sigma (chi2 loss)" if absolute_noise
                  else "residual scale: no absolute noise level (the loss's noise scale is "
                       "fitted); per-incidence variance ratio to it"),
        "incidence_level": {"statistic": "chi2_per_dof" if absolute_noise else "variance_ratio",
                            "test": ("chi-square, dof n_k (1 - p/N)" if absolute_noise else
                                     "F test of the incidence's mean square against the others'"),
                            "min_p_value_sidak": level_p},
        "runs_test": {**pooled, "ordering": "+".join(sorted(kinds)) or "none",
                      "min_p_value_sidak": runs_p},
        "per_incidence": per,
        "posterior_predictive": predictive,
    }
    if absolute_noise:
        out["chi2"] = chi2_test(r, n_params)
    failed = []
    if absolute_noise and _fails(out["chi2"]["p_value"]):
        failed.append("chi2")
    if _fails(level_p):
        failed.append("incidence_level")
    if _fails(pooled["p_value"]) or _fails(runs_p):
        failed.append("runs_test")
    if predictive and (_fails(predictive["chi2"]["p_value"])
                       or _fails(predictive["worst_incidence"]["p_value"])):
        failed.append("posterior_predictive")
    out["failed"] = failed
    out["describes_data"] = not failed
    return out


def _p(p):
    return "n/a" if p is None else (f"{p:.2g}" if p >= 1e-300 else "< 1e-300")


def failure_sentence(goodness: dict, *, has_mcmc: bool, bootstrap: bool) -> str | None:
    """The warning a channel gets when a check failed (None when all passed): what failed, with
    its figures, and what the intervals then mean."""
    failed = goodness.get("failed") or []
    if not failed:
        return None
    parts = []
    per = goodness.get("per_incidence") or []
    # Each part only where its record is there (a file read back is checked field by field,
    # not for agreement between ``failed`` and the records).
    c = goodness.get("chi2")
    if "chi2" in failed and c:
        parts.append(f"chi2/dof = {c['chi2_per_dof']:.3g} (p = {_p(c['p_value'])})")
    lv = goodness.get("incidence_level") or {}
    stat = lv.get("statistic")
    levels = [x for x in per if x.get(stat) is not None]
    if "incidence_level" in failed and levels:
        worst = max(levels, key=lambda x: x[stat])
        what = "chi2/dof" if stat == "chi2_per_dof" else "residual variance / overall noise scale"
        parts.append(f"per incidence {what} up to {worst[stat]:.3g} at theta_i = "
                     f"{worst['theta_i']:g} deg (Sidak-corrected p = "
                     f"{_p(lv.get('min_p_value_sidak'))})")
    rt = goodness.get("runs_test")
    if "runs_test" in failed and rt:
        parts.append(f"residual signs form {rt['runs']} runs along the scans where "
                     f"{rt['expected_runs']:.0f} are expected for noise (runs test p = "
                     f"{_p(rt['p_value'])}): the residuals are structured")
    pp = goodness.get("posterior_predictive")
    if "posterior_predictive" in failed and pp:
        parts.append(f"posterior predictive p = {_p(pp['worst_incidence']['p_value'])} "
                     f"(worst incidence), {_p(pp['chi2']['p_value'])} (chi2)")
    if not parts:
        parts.append(", ".join(str(f) for f in failed))
    then = ("the least-squares standard errors"
            + (" and the MCMC intervals are" if has_mcmc else " are")
            + " conditional on the model and understate the uncertainty of its parameters; ")
    then += ("the bootstrap intervals over incidences (parameters.*.bootstrap) account for the "
             "misfit" if bootstrap else "refit with --bootstrap N (fitlab.fit(..., "
             "bootstrap=N)) for intervals that account for the misfit, or try a richer model")
    return ("THE MODEL DOES NOT DESCRIBE THE DATA (goodness checks at p < "
            f"{goodness.get('p_fail', P_FAIL):g}: " + "; ".join(parts) + "): " + then)


# ---- bootstrap summaries -------------------------------------------------------------------


def bootstrap_summary(samples):
    """Per column of replicate estimates (B, d): {std, p16, p50, p84, p2_5, p97_5} (percentile
    intervals), as lists over the columns."""
    s = np.asarray(samples, float)
    q = np.percentile(s, [2.5, 16, 50, 84, 97.5], axis=0)
    std = s.std(axis=0, ddof=1) if s.shape[0] > 1 else np.full(s.shape[1], np.nan)
    return [{"std": float(std[k]), "p16": float(q[1, k]), "p50": float(q[2, k]),
             "p84": float(q[3, k]), "p2_5": float(q[0, k]), "p97_5": float(q[4, k])}
            for k in range(s.shape[1])]
