"""blackjax's NUTS as fitlab's second posterior sampler (``--sampler nuts``): the same
posterior as emcee (the reference) on the Walter example, its diagnostics, the parameter file
naming it, and the CLI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main

pytest.importorskip("blackjax")

ROOT = Path(__file__).resolve().parents[2]
WALTER = ROOT / "data_formats" / "examples" / "walter_rough_glass.csv"


@pytest.fixture(scope="module")
def problem():
    from fitlab.fitting import channel
    from fitlab.fitting.least_squares import fit_least_squares

    m = fitlab.read(WALTER)
    prep = channel.prepare_channel(m, "rough_dielectric", rows=m.theta_i == 0)
    ls = fit_least_squares(prep["space"], prep["data"], prep["loss"],
                           start_native=prep["start_native"])
    return prep, ls


@pytest.mark.slow
def test_nuts_and_emcee_sample_the_same_posterior(problem):
    """Posterior means agree within 4 Monte Carlo standard errors (std/sqrt(ESS) of each
    sampler), standard deviations within 10 %; NUTS's diagnostics say it is trusted."""
    from fitlab.fitting.mcmc import run_mcmc
    from fitlab.fitting.nuts import run_nuts

    prep, ls = problem
    nu = run_nuts(prep["space"], prep["data"], prep["loss"], ls, seed=0, nsteps=1000)
    em = run_mcmc(prep["space"], prep["data"], prep["loss"], ls, seed=0, nsteps=3000,
                  progress=False)
    assert nu.trustworthy and not nu.warnings, nu.warnings
    assert nu.sampler == "nuts" and nu.samples_native.shape == (4000, 2)
    m1, s1 = nu.samples_native.mean(0), nu.samples_native.std(0)
    m2, s2 = em.samples_native.mean(0), em.samples_native.std(0)
    mcse = np.hypot(s1 / np.sqrt(nu.ess), s2 / np.sqrt(em.ess))
    assert np.all(np.abs(m1 - m2) < 4 * mcse), (m1, m2, mcse)
    np.testing.assert_allclose(s1, s2, rtol=0.1)
    # the posterior's width is the least-squares standard error here (a near-Gaussian posterior)
    np.testing.assert_allclose(s1, ls.stderr, rtol=0.1)


def test_diagnostics_flag_disagreeing_chains():
    """ArviZ's split R-hat and bulk ESS: chains around different values are caught."""
    from fitlab.fitting.nuts import diagnostics

    rng = np.random.default_rng(0)
    good = rng.standard_normal((4, 500, 1))
    ess, rhat = diagnostics(good, ("x",))
    assert rhat[0] < 1.01 and ess[0] > 1000
    bad = good + np.array([0.0, 0.0, 0.0, 3.0])[:, None, None]
    _, rhat = diagnostics(bad, ("x",))
    assert rhat[0] > 1.1


def test_cli_sampler_nuts_writes_it_in_the_file(tmp_path, capsys):
    """Three chains: on a machine with two or more cores they run one per core, the second
    core's spare slot filled by a copy that is dropped (nuts.chain_layout)."""
    out = tmp_path / "fit.json"
    code = main(["fit", str(WALTER), "--model", "rough_dielectric", "--fit-subset",
                 "theta_i == 0", "--mcmc", "--sampler", "nuts", "--mcmc-steps", "500",
                 "--walkers", "3", "--bootstrap", "0", "--out", str(out), "--chain",
                 str(tmp_path / "c.npz"), "--quiet"])
    assert code == 0, capsys.readouterr().err
    r = fitlab.load_fit(out)
    mc = r.record["fits"][0]["mcmc"]
    assert mc["sampler"] == "nuts" and mc["nwalkers"] == 3 and mc["nsteps"] == 500
    assert r.samples("Y").shape == (1500, 2)
    assert r.posterior("Y") is not None
    with np.load(tmp_path / "c.npz") as z:
        chain = z["chain_Y"]  # (draws, chains, coordinates): three different chains
    assert chain.shape == (500, 3, 3)
    assert len({chain[:, k].tobytes() for k in range(3)}) == 3


def test_chains_are_laid_out_one_per_core():
    """As many devices as the chains fill evenly, the chains one after another on each."""
    from fitlab.fitting.nuts import chain_layout

    assert chain_layout(4, 2) == (2, 2)
    assert chain_layout(3, 2) == (2, 2)  # one spare slot on the second device
    assert chain_layout(4, 16) == (4, 1)
    assert chain_layout(4, 1) == (1, 4)
    assert chain_layout(5, 4) == (3, 2)  # 2 + 2 + 1: three devices, no fourth to wait for
    assert chain_layout(1, 8) == (1, 1)


def test_fitlab_gives_jax_one_cpu_device_per_core():
    """fitlab/_jax.py sets XLA's host device count to the cores when JAX has not started (a
    user's own count is kept); NUTS's chains run one per device."""
    import os
    import subprocess
    import sys

    from fitlab._jax import HOST_DEVICES_FLAG, host_cores, host_device_flags

    assert host_device_flags("", 2) == f"{HOST_DEVICES_FLAG}=2"
    assert host_device_flags(f"--a=1 {HOST_DEVICES_FLAG}=5", 2) == f"--a=1 {HOST_DEVICES_FLAG}=5"
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    out = subprocess.run([sys.executable, "-c", "import fitlab, jax; print(jax.device_count())"],
                         env=env, capture_output=True, text=True, check=True).stdout
    assert int(out) == host_cores()


def test_unknown_sampler_is_refused(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["fit", str(WALTER), "--model", "rough_dielectric", "--mcmc", "--sampler", "x"])
    assert exc.value.code == 2
    with pytest.raises(fitlab.errors.FitlabError, match="unknown sampler"):
        fitlab.fit(fitlab.read(WALTER), "rough_dielectric", mcmc=True, sampler="x")
