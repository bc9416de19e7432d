"""The posterior samplers a fit can use, by name: emcee (fitlab/fitting/mcmc.py, the default and
the reference) and NUTS (fitlab/fitting/nuts.py, blackjax). Each is imported when it runs:
the names and descriptions (``fitlab fit --help``) need neither."""

from __future__ import annotations

from typing import Callable, NamedTuple

from fitlab.errors import FitlabError
from fitlab.registry import Registry

#: emcee's default steps per walker (the fit's default: emcee is the default sampler).
MCMC_STEPS = 3000


class Sampler(NamedTuple):
    description: str
    #: run(space, data, loss, ls, *, seed, nsteps, walkers, progress) -> MCMCResult
    #: (``walkers``: emcee's walkers, NUTS's chains)
    run: Callable
    #: the default ``mcmc_steps``: steps per walker (emcee), adaptation steps and draws per
    #: chain (NUTS)
    steps: int


#: The posterior samplers, by name.
SAMPLERS: Registry[Sampler] = Registry("sampler", {
    "emcee": Sampler("affine-invariant ensemble sampler (emcee), the default and the reference",
                     lambda space, data, loss, ls, *, seed, nsteps, walkers, progress: _emcee(
                         space, data, loss, ls, seed=seed, nsteps=nsteps, nwalkers=walkers,
                         progress=progress), MCMC_STEPS),
    "nuts": Sampler("No-U-Turn sampler (blackjax), adapted and drawn in one compiled call, "
                    "one chain per core on the CPU (4 chains unless --walkers); diagnostics by "
                    "ArviZ (fitlab/fitting/nuts.py)",
                    lambda space, data, loss, ls, *, seed, nsteps, walkers, progress: _nuts(
                        space, data, loss, ls, seed=seed, nsteps=nsteps, nchains=walkers or 4,
                        progress=progress), 1000),
})


def _emcee(*args, **kwargs):
    from fitlab.fitting.mcmc import run_mcmc  # on first use: emcee, scipy, JAX

    return run_mcmc(*args, **kwargs)


def _nuts(*args, **kwargs):
    try:
        import blackjax  # noqa: F401
    except ImportError:
        raise FitlabError("the nuts sampler needs blackjax: pip install 'fitlab[samplers]'") \
            from None
    from fitlab.fitting.nuts import run_nuts

    return run_nuts(*args, **kwargs)


def sample_posterior(sampler: str, space, data, loss, ls, *, seed, nsteps, walkers, progress):
    """The posterior of one fit by the sampler named ``sampler`` (:data:`SAMPLERS`)."""
    if sampler not in SAMPLERS:
        raise FitlabError(str(SAMPLERS.unknown(sampler)))
    return SAMPLERS[sampler].run(space, data, loss, ls, seed=seed, nsteps=nsteps,
                                 walkers=walkers, progress=progress)
