"""MCMC effective samples per second on the Walter example: emcee with fitlab's jitted,
vectorized log-posterior (one call per half-step for all walkers, as ``fitlab fit --mcmc``
runs it) against emcee with a plain-NumPy log-probability of the same model, prior and
likelihood called once per walker (emcee's default, non-vectorized).

Same problem as ``bench_fit_least_squares.py`` (``fitlab fit walter_rough_glass.csv --model
rough_dielectric --fit-subset 'theta_i == 0' --mcmc``): coordinates u_alpha, u_scale (the unit
box of the log transforms; uniform prior) and log σ_r (Jeffreys prior for the relative loss's
noise scale). Both samplers get the same walkers (fitlab's default 32), steps, start positions
(fitlab's ``mcmc_setup``: a ball around the least-squares optimum) and emcee random state
(seed); fitlab's log-posterior compilation is timed separately and excluded.

Effective samples = walkers × (steps − burn) / τ_max, with τ from emcee.autocorr and burn =
min(steps/2, 3 τ_max), as fitlab reports it. The run also reports where the time goes: the
log-probability alone (evaluations per second, per walker) and emcee's own per-step cost
(measured with a trivial vectorized log-probability), which bounds the achievable ratio.

Usage: python benchmarks/bench_mcmc.py [--steps 3000] [--repeat 3] [--seed 0]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _walter_fit import (  # noqa: E402
    Problem, load_average, machine, machine_line, median, np_native_from_unit,
    np_residuals_native, timed,
)


def np_log_prob_factory(p: Problem):
    n = p.value.size

    def log_prob(x):
        u, log_s = x[:2], x[2]
        if not np.all((u >= 0) & (u <= 1)):
            return -np.inf
        r = np_residuals_native(np_native_from_unit(u, p.lo, p.hi), p)
        lp = -0.5 * float(r @ r) * math.exp(-2.0 * log_s) - n * log_s
        return lp if math.isfinite(lp) else -np.inf

    return log_prob


def ess_of(chain, nwalkers, nsteps):
    import emcee

    tau = np.asarray(emcee.autocorr.integrated_time(chain, quiet=True), dtype=float)
    tau_max = float(np.nanmax(tau))
    burn = int(min(nsteps // 2, np.ceil(3 * tau_max)))
    return nwalkers * (nsteps - burn) / tau_max, tau, burn


def run(steps=3000, repeat=3, seed=0, quiet=False):
    say = (lambda *a, **k: None) if quiet else print
    import logging

    import emcee

    from fitlab.fitting import least_squares as fls
    from fitlab.fitting.mcmc import mcmc_setup

    logging.getLogger("emcee").setLevel(logging.ERROR)
    info = machine()
    p = Problem()
    ls = fls.fit_least_squares(p.space, p.data, p.loss, start_native=p.start_native, seed=seed)
    t_setup, setup = timed(lambda: mcmc_setup(p.space, p.data, p.loss, ls, seed=seed))
    fl_logp, p0 = setup["log_prob"], setup["p0"]
    assert setup["names"] == ("alpha", "scale", "log_noise")
    nwalkers, ndim = p0.shape
    np_logp = np_log_prob_factory(p)

    t_compile, lp_fl = timed(lambda: fl_logp(p0))  # trace + compile + first call
    lp_np = np.array([np_logp(x) for x in p0])
    lp_agree = float(np.max(np.abs(lp_fl - lp_np) / np.maximum(np.abs(lp_np), 1e-300)))

    def sample(log_prob, vectorize):
        s = emcee.EnsembleSampler(nwalkers, ndim, log_prob, vectorize=vectorize)
        s.random_state = np.random.RandomState(seed).get_state()
        s.run_mcmc(p0, steps)
        return s

    load_before = load_average()
    t_fl, t_np, samplers = [], [], {}
    for _ in range(repeat):
        dt, samplers["fl"] = timed(lambda: sample(fl_logp, True))
        t_fl.append(dt)
        dt, samplers["np"] = timed(lambda: sample(np_logp, False))
        t_np.append(dt)
    # Where the time goes: the log-probability alone, and emcee's own per-step work.
    x = p0.copy()
    n_eval = 200
    t_lp_fl = median([timed(lambda: fl_logp(x[: nwalkers // 2]))[0] for _ in range(n_eval)])
    t_lp_np = median([timed(lambda: [np_logp(w) for w in x[: nwalkers // 2]])[0]
                      for _ in range(n_eval // 10)])

    def trivial(xs):
        return -0.5 * np.sum(xs * xs, axis=1)

    t_emcee = median([timed(lambda: sample(trivial, True))[0] for _ in range(repeat)])
    load_after = load_average()

    res = {**info, "steps": steps, "walkers": nwalkers, "repeat": repeat, "seed": seed,
           "load_before": load_before, "load_after": load_after,
           "fitlab_compile_s": t_compile, "setup_s": t_setup, "lp_max_rel_diff": lp_agree}
    for side in ("fl", "np"):
        s = samplers[side]
        ess, tau, burn = ess_of(s.get_chain(), nwalkers, steps)
        t = median(t_fl if side == "fl" else t_np)
        res[f"{side}_seconds"] = t
        res[f"{side}_ess"] = ess
        res[f"{side}_tau"] = tau.tolist()
        res[f"{side}_ess_per_s"] = ess / t
        res[f"{side}_acceptance"] = float(s.acceptance_fraction.mean())
        flat = s.get_chain(discard=burn, flat=True)
        res[f"{side}_median"] = np.median(flat, axis=0).tolist()
        res[f"{side}_std"] = flat.std(axis=0).tolist()
    chain_fl, chain_np = samplers["fl"].get_chain(), samplers["np"].get_chain()
    res["chains_identical_steps"] = int(np.argmax(np.any(chain_fl != chain_np, axis=(1, 2)))
                                        if np.any(chain_fl != chain_np) else steps)
    res["ratio_ess_per_s"] = res["fl_ess_per_s"] / res["np_ess_per_s"]
    res["ratio_time"] = res["np_seconds"] / res["fl_seconds"]
    res["logprob_half_step_fl_s"] = t_lp_fl
    res["logprob_half_step_np_s"] = t_lp_np
    res["ratio_logprob"] = t_lp_np / t_lp_fl
    res["emcee_overhead_per_step_s"] = t_emcee / steps
    # The best ratio any log-probability could give here: NumPy's time over emcee's own.
    res["ratio_bound"] = res["np_seconds"] / t_emcee
    same = (np.allclose(res["fl_median"], res["np_median"], rtol=0.02,
                        atol=0.02 * np.max(res["np_std"]))
            and np.allclose(res["fl_std"], res["np_std"], rtol=0.2))
    res["agree"] = bool(same and lp_agree < 1e-9)

    say(f"machine : {machine_line(info)}; load avg {load_before} -> {load_after}")
    say(f"problem : Walter example theta_i == 0, {p.value.size} rows; coordinates "
        f"{', '.join(setup['names'])}; {nwalkers} walkers x {steps} steps, seed {seed}")
    say(f"log-posterior agreement (start positions): max rel. diff {lp_agree:.1e}; chains "
        f"identical for the first {res['chains_identical_steps']} of {steps} steps")
    for side, label in (("fl", "fitlab (jitted, vectorized)"), ("np", "NumPy (per walker)")):
        say(f"{label:>28}: {res[side + '_seconds']:8.3f} s, tau {np.round(res[side + '_tau'], 1)}, "
            f"ESS {res[side + '_ess']:8.0f}, {res[side + '_ess_per_s']:9.0f} ESS/s, acceptance "
            f"{res[side + '_acceptance']:.2f}, posterior median "
            f"{np.round(res[side + '_median'], 5)}")
    say(f"fitlab log-posterior first call (trace + compile) {t_compile:.2f} s, excluded")
    say(f"ESS/s ratio fitlab/NumPy: {res['ratio_ess_per_s']:.1f}x  (wall-time ratio "
        f"{res['ratio_time']:.1f}x)")
    say(f"where the time goes: log-probability of {nwalkers // 2} walkers (one half-step): "
        f"fitlab {t_lp_fl * 1e6:.0f} us, NumPy {t_lp_np * 1e6:.0f} us "
        f"({res['ratio_logprob']:.0f}x); "
        f"emcee's own work {res['emcee_overhead_per_step_s'] * 1e6:.0f} us per step, so no "
        f"log-probability can make emcee more than {res['ratio_bound']:.1f}x faster than the "
        f"NumPy run here")
    say(f"posteriors agree: {res['agree']}")
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    res = run(steps=args.steps, repeat=args.repeat, seed=args.seed)
    return 0 if res["agree"] else 1


if __name__ == "__main__":
    sys.exit(main())
