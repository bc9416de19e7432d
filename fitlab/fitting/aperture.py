"""The fit's model of an instrument's aperture: rows that average over a solid angle (a detector
cone or bin, a divergent source: data_formats/measurement_csv.md, "Aperture") are predicted by
the aperture-averaged model, a weighted sum over quadrature nodes (fitlab.aperture) built once
per dataset and carried in ``FitData.weights``.

The quadrature's own error is measured, not assumed: at the fitted parameters the rule of order
n is compared with the rule of order 2n, row by row (in units of the residuals' noise: σ for the
chi2 loss) and as the shift of the least-squares optimum the difference would cause,
δ = −(JᵀJ)⁻¹ Jᵀ Δr, in units of each parameter's standard error. The order is chosen
automatically unless given: start at :data:`START_ORDER`, and while the shift exceeds
:data:`PARAMETER_TOLERANCE` standard errors, refit at twice the order (up to
:data:`MAX_AUTO_ORDER`). The parameter file records the order, the rule and the error
(``fits[k].aperture``, data_formats/fit_json.md).
"""

from __future__ import annotations

import numpy as np

from fitlab.aperture import check_order, row_rule
from fitlab.fitting.least_squares import ROW_MASK, FitData
from fitlab.fitting.losses import residuals

#: First order of the automatic choice (a cone: 4 × 8 nodes, a bin: 4 × 4).
START_ORDER = 4
#: Largest order the automatic choice goes to.
MAX_AUTO_ORDER = 16
#: The quadrature is accurate enough when the optimum it causes moves by less than this many
#: standard errors of each parameter (order n against 2n).
PARAMETER_TOLERANCE = 0.1

RULE = ("cosine-weighted mean over each row's aperture: detector cone = Gauss-Legendre in "
        "1 - cos(psi) (n nodes) x midpoint rule in the azimuth around the axis (2n), clipped at "
        "the surface plane; theta/phi bin = Gauss-Legendre in theta (n) x in phi (n), weight "
        "|cos theta| sin theta; divergent source = the cone rule around wi, times the "
        "detector's rule; weights normalized to sum 1")


def nodes(m, rows, order: int):
    """(wi nodes (R, K, 3), wo nodes (R, K, 3), weights (R, K)) of the Measurement's ``rows``
    (a boolean mask or indices) at quadrature ``order``."""
    pick = lambda a: None if a is None else np.asarray(a)[rows]  # noqa: E731
    return row_rule(m.wi[rows], m.wo[rows], order, aperture_deg=pick(m.aperture_deg),
                    bin_deg=pick(m.bin_o_deg),
                    source_divergence_deg=pick(m.source_divergence_deg))


def with_nodes(data: FitData, m, rows, order: int) -> FitData:
    """``data`` (the fitted ``rows`` of ``m``) with the aperture nodes of ``order``."""
    from fitlab._jax import jax

    wi, wo, w = nodes(m, rows, order)
    return data._replace(wi=jax.device_put(wi), wo=jax.device_put(wo),
                         weights=jax.device_put(w))


def predict_rows(space, native, m, rows, order: int) -> np.ndarray:
    """scale · (aperture-averaged f) of the Measurement's ``rows`` at native parameter values."""
    wi, wo, w = nodes(m, rows, order)
    return np.sum(w * space.predict(native, wi, wo), axis=-1)


def quadrature_error(space, ls, data: FitData, m, rows, order: int, loss: str) -> dict:
    """The rule of ``order`` against the rule of 2·``order`` at the fitted parameters: per row
    (residual units over the residuals' noise scale) and as the optimum's shift in standard
    errors (linearized with the Jacobian at the optimum)."""
    value = np.asarray(data.value)
    consts = {k: np.asarray(v) for k, v in data.consts.items()}
    mask = consts.get(ROW_MASK, np.ones_like(value))
    r_n = np.asarray(residuals(loss, predict_rows(space, ls.native, m, rows, order), value,
                               consts)) * mask
    r_2n = np.asarray(residuals(loss, predict_rows(space, ls.native, m, rows, 2 * order), value,
                                consts)) * mask
    dr = r_2n - r_n
    noise = max(float(ls.noise_scale), 1e-300)
    out = {"reference_order": 2 * order,
           "max_row_error": float(np.max(np.abs(dr)) / noise),
           "rms_row_error": float(np.sqrt(np.mean(dr * dr)) / noise),
           "row_error_unit": "residual noise (sigma for the chi2 loss)"}
    shift = {}
    if ls.jacobian is not None:
        J = np.asarray(ls.jacobian)
        delta = -np.linalg.pinv(J.T @ J) @ (J.T @ dr)
        for name, d, s in zip(space.names, delta, ls.stderr):
            shift[name] = float(abs(d) / s) if s > 0 and np.isfinite(s) else None
    out["parameter_shift"] = shift
    known = [v for v in shift.values() if v is not None]
    out["max_parameter_shift"] = max(known) if known else None
    out["parameter_shift_unit"] = "standard errors"
    out["tolerance"] = PARAMETER_TOLERANCE
    out["within_tolerance"] = bool(known) and max(known) <= PARAMETER_TOLERANCE
    return out


def settle_order(space, ls, data: FitData, m, rows, loss: str, order: int, *, auto: bool,
                 refit, log=lambda msg: None):
    """The least-squares result at an accurate enough order: with ``auto``, refit (``refit(data,
    start_native) -> LeastSquaresResult``) at twice the order while the quadrature error moves
    the optimum by more than PARAMETER_TOLERANCE standard errors. Returns (ls, data, record,
    warnings); ``record`` is the parameter file's ``aperture`` entry."""
    while True:
        err = quadrature_error(space, ls, data, m, rows, order, loss)
        shift = err["max_parameter_shift"]
        log(f"  aperture quadrature: order {order}, {data.weights.shape[1]} nodes per row; "
            f"against order {2 * order}: parameters move "
            f"{'n/a' if shift is None else f'{shift:.3g}'} standard errors, rows "
            f"{err['max_row_error']:.3g} noise at most")
        if not auto or err["within_tolerance"] or 2 * order > MAX_AUTO_ORDER or shift is None:
            break
        order *= 2
        data = with_nodes(data, m, rows, order)
        ls = refit(data, ls.native)
    record = {"rows": int(np.count_nonzero(aperture_rows(m)[rows])),
              "order": order, "order_choice": "auto" if auto else "given",
              "nodes_per_row": int(data.weights.shape[1]), "rule": RULE,
              "quadrature_error": err}
    warnings = []
    if not err["within_tolerance"] and shift is not None:
        warnings.append(
            f"the aperture quadrature of order {order} is not accurate enough: order "
            f"{2 * order} moves the optimum by {shift:.3g} standard errors (tolerance "
            f"{PARAMETER_TOLERANCE:g}); refit with a higher aperture order"
            + ("" if auto else " (aperture_order / --aperture-order)"))
    return ls, data, record, warnings


def aperture_rows(m) -> np.ndarray:
    """Rows of ``m`` that average over a solid angle (a cone, a bin or a divergent source)."""
    from fitlab.aperture import bin_has_extent

    out = np.zeros(m.n, dtype=bool)
    if m.aperture_deg is not None:
        out |= m.aperture_deg > 0
    if m.bin_o_deg is not None:
        out |= bin_has_extent(m.bin_o_deg)
    if m.source_divergence_deg is not None:
        out |= m.source_divergence_deg > 0
    return out


def start_order(aperture_order) -> tuple[int, bool]:
    """(first order, whether the order is chosen automatically) for ``aperture_order`` (None:
    automatic)."""
    if aperture_order is None:
        return START_ORDER, True
    return check_order(aperture_order), False


__all__ = ["START_ORDER", "MAX_AUTO_ORDER", "PARAMETER_TOLERANCE", "nodes", "with_nodes",
           "predict_rows", "quadrature_error", "settle_order", "start_order"]
