"""fitlab's Levenberg–Marquardt: the single fit's solver (:func:`lm_until`, a
``while_loop``) and the batched fits' (:func:`lm_queue`, fitlab.fitting.batch), one body.

jaxopt's Levenberg–Marquardt (the reference, fitlab.fitting.solvers) evaluates the model for
the residual, for the Jacobian and for the trial point each step, and vmapped over thousands of
datasets and starts every lane of its ``while_loop`` runs until the slowest one stops (median
20 steps, a chunk's slowest 71 on the Walter benchmark). Here:

* one forward-mode pass per step: the residuals and the Jacobian at the trial point together
  (``jax.jacfwd`` with the value as auxiliary output); a rejected step costs that pass too;
* the same damping and stopping rule as jaxopt's (Madsen & Nielsen, "Introduction to
  Optimization and Data Fitting", 2010, Algorithm 3.16): initial damping τ · max diag(JᵀJ), the
  gain ratio ρ = ΔF / ΔL, μ ← μ · max(1/3, 1 − (2ρ − 1)³) on success and μ ← μ ν, ν ← 2ν on
  failure; stop when ‖Jᵀr‖∞ ≤ gtol or ‖h‖ ≤ xtol (‖z‖ + xtol). The damped normal equations
  (JᵀJ + μ I) h = −Jᵀr are solved by Cholesky;
* batched (:func:`lm_queue`): a fixed number of lanes, each running one start at a time; a lane
  whose run ends takes the next start, so the batch costs the sum of its runs' steps.

A run reports whether its stopping rule was met (``converged``), else it ran out of steps
(``max_iterations``), and whether it ended finite.

Why an own solver and not Optimistix's ``LevenbergMarquardt`` under vmap (the maintained
library the project would otherwise use): measured on the same datasets, starts and residuals
(benchmarks/batched_lm.py, 2 vCPUs), this one is several times faster warm, compiles in about
half the time, and reaches the same optima (benchmarks/README.md, "Batched fits").
"""

from __future__ import annotations

from fitlab._jax import jax, jnp, jsp_linalg


def value_and_jacobian(f):
    """x -> (f(x), ∂f/∂x) in one forward-mode pass."""

    def both(x, *args):
        def f2(y):
            v = f(y, *args)
            return v, v

        J, v = jax.jacfwd(f2, has_aux=True)(x)
        return v, J

    return both


def _lm(residual, *, xtol: float, gtol: float, tau: float):
    """(initial state at z0, one step) of the solver, each given the residual's ``args``: the
    shared body of :func:`lm_until` and :func:`lm_queue`.

    The model is evaluated in the step alone: the state starts with the flag ``first``, whose
    step evaluates z0 itself (a zero step, accepted) and sets the initial damping; the compiled
    loop then holds one copy of the model's forward-mode pass, not one for the start and one for
    the steps (measured, alternating runs: the single fit's local stage compiles in 0.88-0.90 s
    against 0.99-1.17 s on the Walter example; 0.38 s against 0.58-0.76 s on the brown vinyl's
    Lambert + GGX conductor under the tests' XLA settings)."""
    both = value_and_jacobian(residual)

    def init(z0, args):
        p = z0.shape[0]
        r0 = jax.eval_shape(lambda z: residual(z, args), z0)
        return dict(z=z0, r=jnp.zeros(r0.shape, r0.dtype), A=jnp.zeros((p, p), z0.dtype),
                    g=jnp.zeros((p,), z0.dtype), cost=jnp.asarray(jnp.inf, z0.dtype),
                    mu=jnp.asarray(1.0, z0.dtype), nu=jnp.asarray(2.0, z0.dtype),
                    done=jnp.asarray(False), first=jnp.asarray(True),
                    iters=jnp.asarray(0, jnp.int32))

    def step(s, args):
        first = s["first"]
        eye = jnp.eye(s["z"].shape[0], dtype=s["z"].dtype)
        # the first step: A = 0, μ = 1 and g = 0, so h = 0 exactly (z0 itself is evaluated)
        h = jsp_linalg.cho_solve(jsp_linalg.cho_factor(s["A"] + s["mu"] * eye), -s["g"])
        small = ~first & (jnp.linalg.norm(h) <= xtol * (jnp.linalg.norm(s["z"]) + xtol))
        z_t = s["z"] + h
        r_t, J_t = both(z_t, args)
        cost_t = 0.5 * jnp.sum(r_t * r_t)
        predicted = 0.5 * h @ (s["mu"] * h - s["g"])
        rho = (s["cost"] - cost_t) / predicted
        ok = first | (jnp.isfinite(cost_t) & (rho > 0) & ~small)
        A_t, g_t = J_t.T @ J_t, J_t.T @ r_t
        mu_ok = jnp.where(first, tau * jnp.max(jnp.diag(A_t)),
                          s["mu"] * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3))
        new = dict(
            z=jnp.where(ok, z_t, s["z"]), r=jnp.where(ok, r_t, s["r"]),
            A=jnp.where(ok, A_t, s["A"]), g=jnp.where(ok, g_t, s["g"]),
            cost=jnp.where(ok, cost_t, s["cost"]),
            mu=jnp.where(ok, mu_ok, s["mu"] * s["nu"]).astype(s["mu"].dtype),
            nu=jnp.where(ok, 2.0, 2.0 * s["nu"]).astype(s["nu"].dtype),
            done=small | (ok & (jnp.max(jnp.abs(g_t)) <= gtol)), first=jnp.asarray(False),
            iters=s["iters"] + jnp.where(first, 0, 1).astype(jnp.int32))
        return jax.tree.map(lambda old, nw: jnp.where(s["done"], old, nw), s, new)

    return init, step


def _result(s):
    finite = jnp.all(jnp.isfinite(s["z"])) & jnp.isfinite(s["cost"])
    return {"z": s["z"], "cost": s["cost"], "iters": s["iters"], "rule_met": s["done"],
            "finite": finite}


def lm_until(residual, z0, args, *, maxiter: int, xtol: float, gtol: float, tau: float):
    """Minimise ½‖residual(z, args)‖² from ``z0`` (p,): a ``while_loop`` that ends when the
    stopping rule is met or after ``maxiter`` steps (one more pass evaluates z0). Returns
    ``z``, ``cost``, ``iters`` (steps taken), ``rule_met`` and ``finite``. Traceable: the single
    fit maps it over its starts (fitlab.fitting.solvers)."""
    init, step = _lm(residual, xtol=xtol, gtol=gtol, tau=tau)
    return _result(jax.lax.while_loop(
        lambda s: s["first"] | (~s["done"] & (s["iters"] < maxiter)),
        lambda s: step(s, args), init(z0, args)))


def lm_queue(residual, Z0, problems, which, n, *, lanes: int, maxiter: int, xtol: float,
             gtol: float, tau: float, between: int = 4):
    """:func:`lm_until` from each start ``Z0[i]`` (i < ``n``; Z0 is (M, p)) on the problem
    ``problems[which[i]]`` (a pytree with a leading dataset axis), on ``lanes`` lanes at once: a
    lane whose run meets its stopping rule, or has spent ``maxiter`` steps, writes its end and
    takes the next start (as the simulator's walk regenerates a lane's path), so the batch costs
    the sum of its runs' steps over ``lanes``, not the number of runs times the slowest one's
    (a vmapped ``while_loop``) or a fixed budget per run. Each run is
    :func:`lm_until`'s, step for step. Returns per start ``z``, ``cost``, ``iters``,
    ``rule_met`` and ``finite`` (starts from ``n`` on: not run, ``finite`` False). The lanes
    are refilled every ``between`` steps (a lane whose run ended waits for at most
    ``between`` - 1 steps; the refill's bookkeeping costs about one step)."""
    init, step = _lm(residual, xtol=xtol, gtol=gtol, tau=tau)
    M = Z0.shape[0]
    L = min(int(lanes), M)
    Z0, which = jnp.asarray(Z0), jnp.asarray(which)

    def take(idx):
        return jax.tree.map(lambda x: x[which[idx]], problems)

    idx = jnp.arange(L)
    state = jax.vmap(init)(Z0[idx], take(idx))
    out = jax.vmap(_result)(jax.vmap(init)(Z0, jax.tree.map(lambda x: x[which], problems)))
    active = idx < n

    def advance(_, st, args):
        # a run that has spent maxiter steps stays put (a run that met its rule does: step)
        held = ~st["first"] & (st["iters"] >= maxiter)
        new = jax.vmap(step)(st, args)
        return jax.tree.map(
            lambda a, b: jnp.where(held.reshape((-1,) + (1,) * (a.ndim - 1)), a, b), st, new)

    def body(c):
        state, idx, nxt, out, active = c
        args = take(idx)
        state = jax.lax.fori_loop(0, int(between), lambda i, st: advance(i, st, args), state)
        ended = active & ~state["first"] & (state["done"] | (state["iters"] >= maxiter))
        res = jax.vmap(_result)(state)
        out = jax.tree.map(lambda o, r: o.at[jnp.where(ended, idx, M)].set(r, mode="drop"),
                           out, res)
        new = nxt + jnp.cumsum(ended) - 1  # the next starts, in order, to the ended lanes
        refill = ended & (new < n)
        idx = jnp.where(refill, new, idx)
        fresh = jax.vmap(init)(Z0[idx], take(idx))
        state = jax.tree.map(
            lambda a, b: jnp.where(refill.reshape((-1,) + (1,) * (a.ndim - 1)), b, a),
            state, fresh)
        return state, idx, nxt + jnp.sum(ended), out, (active & ~ended) | refill

    _, _, _, out, _ = jax.lax.while_loop(lambda c: jnp.any(c[4]), body,
                                         (state, idx, jnp.asarray(L), out, active))
    return out


__all__ = ["lm_until", "lm_queue", "value_and_jacobian"]
