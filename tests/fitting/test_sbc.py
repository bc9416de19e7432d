"""Simulation-based calibration (Talts et al. 2018) of fitlab's posterior samplers: parameters
drawn from the prior, data simulated from the likelihood the samplers assume, and the rank of
each true value among its posterior's draws, which is uniform when the sampler is calibrated.

The problem is one where the likelihood is exactly generative: Oren–Nayar (albedo in [0, 1],
σ in [0, π/2], both with a uniform prior on their linear unit-box coordinate, which is fitlab's
prior) observed at 24 direction pairs with Gaussian noise of known σ_y = 0.01 (the chi2 loss,
so no noise scale is sampled). Per sampler: N datasets, L = 39 thinned draws per posterior,
ranks in 0..L pooled into 8 bins; a χ² test of uniformity per parameter must not reject at
p < 1e-3 (fixed seeds). NUTS runs all datasets in one batched call (fitlab.fit_many with
mcmc=True); emcee, the reference, one fit at a time.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

import fitlab

N_DATASETS = 96
L = 39
BINS = 8
SIGMA_Y = 0.01


def _design():
    rng = np.random.default_rng(11)
    t_i = rng.uniform(0, 70, 24)
    t_o = rng.uniform(0, 80, 24)
    p_o = rng.uniform(0, 360, 24)

    def d(t, p):
        t, p = np.radians(t), np.radians(p)
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)

    return d(t_i, np.zeros(24)), d(t_o, p_o), t_i, t_o, p_o


def _datasets(seed):
    """(truth (N, 2), Measurements) with the prior's draws and Gaussian data."""
    from fitlab.io.measurement import Measurement

    wi, wo, t_i, t_o, p_o = _design()
    rng = np.random.default_rng(seed)
    truth = np.stack([rng.uniform(0, 1, N_DATASETS), rng.uniform(0, np.pi / 2, N_DATASETS)],
                     axis=1)
    ms = []
    for k, (a, s) in enumerate(truth):
        f = np.asarray(fitlab.eval_bsdf("oren_nayar", {"albedo": a, "sigma": s}, wi, wo))
        y = f + SIGMA_Y * rng.standard_normal(f.shape)
        n = len(y)
        ms.append(Measurement(path=f"sbc_{k}", sha256="", theta_i=t_i, phi_i=np.zeros(n),
                              theta_o=t_o, phi_o=p_o, wi=wi, wo=wo, value=y,
                              sigma=np.full(n, SIGMA_Y), channel=np.zeros(n, int),
                              channel_names=("Y",), wavelength_nm=None, quantity="bsdf",
                              file_quantity="bsdf", metadata={}, lines=np.zeros(n, int)))
    return truth, ms


def _ranks(samples: np.ndarray, truth: np.ndarray, rng) -> np.ndarray:
    """Rank of each true value among L draws thinned evenly from the posterior's samples."""
    idx = np.linspace(0, samples.shape[0] - 1, L).astype(int)
    draws = samples[idx]
    return np.sum(draws < truth[None], axis=0)


def _uniformity_p(ranks: np.ndarray) -> np.ndarray:
    """χ² p-value of the ranks (0..L) pooled into BINS equal bins, per parameter."""
    out = []
    for r in ranks.T:
        counts = np.bincount((r * BINS) // (L + 1), minlength=BINS)
        out.append(stats.chisquare(counts).pvalue)
    return np.array(out)


@pytest.mark.slow
@pytest.mark.optimized  # 96 NUTS chains in one compiled call: 281 s at -O0, 52 s optimized (alone)
def test_nuts_is_calibrated():
    pytest.importorskip("blackjax")
    truth, ms = _datasets(seed=5)
    r = fitlab.fit_many(ms, "oren_nayar", mcmc=True, mcmc_steps=400, walkers=4, chunk=96)
    rng = np.random.default_rng(0)
    ranks = np.array([_ranks(f.mcmc.samples_native, t, rng) for f, t in zip(r.fits, truth)])
    p = _uniformity_p(ranks)
    print(f"NUTS SBC: uniformity p-values {p}")
    assert np.all(p > 1e-3), (p, np.bincount(ranks[:, 0] * BINS // (L + 1), minlength=BINS))
    # the check has power: posteriors shifted by one standard deviation are rejected
    shifted = np.array([_ranks(f.mcmc.samples_native + f.mcmc.samples_native.std(0), t, rng)
                        for f, t in zip(r.fits, truth)])
    assert np.all(_uniformity_p(shifted) < 1e-3)


@pytest.mark.slow
def test_emcee_is_calibrated():
    from fitlab.fitting import channel
    from fitlab.fitting.least_squares import fit_least_squares
    from fitlab.fitting.mcmc import run_mcmc

    truth, ms = _datasets(seed=6)
    rng = np.random.default_rng(0)
    ranks = []
    for m, t in zip(ms[:64], truth[:64]):
        prep = channel.prepare_channel(m, "oren_nayar", rows=np.ones(m.n, bool))
        ls = fit_least_squares(prep["space"], prep["data"], prep["loss"], n_starts=2,
                               start_native=prep["start_native"])
        mc = run_mcmc(prep["space"], prep["data"], prep["loss"], ls, seed=1, nsteps=1500,
                      progress=False)
        ranks.append(_ranks(mc.samples_native, t, rng))
    ranks = np.array(ranks)
    p = _uniformity_p(ranks)
    print(f"emcee SBC: uniformity p-values {p}")
    assert np.all(p > 1e-3), p
