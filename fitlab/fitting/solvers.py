"""The single fit's Levenberg–Marquardt solver, by name (``fitlab fit --local-solver``,
``fitlab.fit(..., local_solver=)``).

- ``fitlab`` (the default): fitlab.fitting.lm's solver as a ``while_loop`` that ends when
  the start met its stopping rule (or at the step limit): one forward-mode pass a step (the
  residuals and the Jacobian at the trial point together), the starts one after another. The batched
  fits (fitlab.fitting.batch) run the same step with a fixed budget.
- ``jaxopt``: jaxopt's ``LevenbergMarquardt`` (the reference the default is measured against),
  the starts one after another: it evaluates the model for the residual, the Jacobian and the trial
  point separately.

Both use the same damping, the same stopping rule (Madsen & Nielsen 2010, Algorithm 3.16:
‖Jᵀr‖∞ ≤ gtol or ‖h‖ ≤ xtol (‖z‖ + xtol)), Cholesky on the damped normal equations and the same
tolerances, and reach the same optima (tests/fitting/test_local_solvers.py). Measured warm on a
joint three-channel glTF conversion fit (8,043 rows, 7 free parameters, 5 starts;
benchmarks/bench_global_stage.py for the single-channel figures): 2.3 s against 6.5 s.

The names and descriptions need neither JAX nor jaxopt (``fitlab fit --help``).
"""

from __future__ import annotations

import functools
from typing import Callable, NamedTuple

from fitlab.registry import Registry


class LocalSolver(NamedTuple):
    description: str
    #: the parameter file's ``solver.algorithm``
    algorithm: str
    #: (residual, maxiter, xtol, gtol, tau) -> run_lm(z0, problem) -> (z, iters, rule_unmet)
    make: Callable


def _fitlab(residual, maxiter, xtol, gtol, tau):
    from fitlab.fitting.lm import lm_until

    def run_lm(z0, problem):
        sol = lm_until(residual, z0, problem, maxiter=maxiter, xtol=xtol, gtol=gtol, tau=tau)
        return sol["z"], sol["iters"], ~sol["rule_met"]

    return run_lm


def _jaxopt(residual, maxiter, xtol, gtol, tau):
    import jaxopt

    solver = jaxopt.LevenbergMarquardt(residual_fun=residual, maxiter=maxiter,
                                       damping_parameter=tau, stop_criterion="madsen-nielsen",
                                       xtol=xtol, gtol=gtol, solver="cholesky",
                                       materialize_jac=True, implicit_diff=False, jit=True)

    def run_lm(z0, problem):
        sol = solver.run(z0, problem)
        # jaxopt's own stopping test (its loop's condition): still true after the loop means
        # the step limit, not the Madsen–Nielsen rule, ended the run.
        return (sol.params, sol.state.iter_num,
                solver._cond_fun(((sol.params, sol.state), ((problem,), {}))))

    return run_lm


LOCAL_SOLVERS: Registry[LocalSolver] = Registry("local solver", {
    "fitlab": LocalSolver("one forward-mode pass a step, stops when every start has met its "
                          "rule (default)",
                          "fitlab Levenberg-Marquardt (Madsen-Nielsen stopping rule)", _fitlab),
    "jaxopt": LocalSolver("jaxopt's LevenbergMarquardt, the reference (about 3x slower)",
                          "jaxopt LevenbergMarquardt (Madsen-Nielsen stopping rule)", _jaxopt),
})
DEFAULT_LOCAL_SOLVER = LOCAL_SOLVERS.names()[0]


@functools.lru_cache(maxsize=None)
def algorithm(name: str) -> str:
    return LOCAL_SOLVERS[name].algorithm


def add_local_solver_option(parser) -> None:
    """``--local-solver NAME`` on a command that fits (fit, compare)."""
    parser.add_argument("--local-solver", choices=LOCAL_SOLVERS.names(),
                        default=DEFAULT_LOCAL_SOLVER,
                        help="the Levenberg-Marquardt implementation: " + "; ".join(
                            f"{k}: {v.description}" for k, v in LOCAL_SOLVERS.items()))


__all__ = ["LOCAL_SOLVERS", "DEFAULT_LOCAL_SOLVER", "LocalSolver", "add_local_solver_option",
           "algorithm"]
