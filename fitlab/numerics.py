"""Gradient-safe numerics: the one place for clamps and guarded operations.

``jnp.where(c, f(x), 0)`` still differentiates ``f`` at the dead branch, so a NaN there poisons
the gradient. Every guarded operation here uses the double-where pattern::

    safe = jnp.where(ok, x, 1.0)
    y = jnp.where(ok, f(safe), 0.0)
"""

from __future__ import annotations

from fitlab._jax import jnp

#: Smallest microfacet width α any model evaluates with (pbrt and Mitsuba clamp in one place too).
#: Widths below this are treated as this value; the lower bound of every α parameter is this.
ALPHA_MIN = 1e-4


def clamp_alpha(alpha):
    """Clamp a microfacet width to ``[ALPHA_MIN, inf)``."""
    return jnp.maximum(alpha, ALPHA_MIN)


def safe_sqrt(x):
    """sqrt(max(x, 0)) with a finite gradient everywhere (0 where x <= 0)."""
    ok = x > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, x, 1.0)), 0.0)


def safe_div(num, den, fallback=0.0):
    """num / den where den != 0, ``fallback`` elsewhere; gradients stay finite."""
    ok = den != 0
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), fallback)


def safe_rsqrt(x):
    """1/sqrt(x) for x > 0, 0 elsewhere."""
    ok = x > 0
    return jnp.where(ok, 1.0 / jnp.sqrt(jnp.where(ok, x, 1.0)), 0.0)


def sign_nonzero(x):
    """Sign of x with sign(0) = +1 (a direction on the horizon counts as the outside)."""
    one = jnp.ones((), dtype=x.dtype)  # typed constants: no float64 intermediate under x64
    return jnp.where(x < 0, -one, one)
