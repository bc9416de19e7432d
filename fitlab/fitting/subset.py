"""``--fit-subset`` expressions: a safe, tiny language over the measurement's columns.

    theta_i == 0
    theta_i < 45 and theta_o > 90
    not (abs(phi_o) < 1) or channel == 'R'

Names: theta_i, phi_i, theta_o, phi_o (degrees), value, channel, row (0-based row index, so
``row % 10 == 0`` thins large scans deterministically), specular_deg (angle in degrees between
wo and the mirror direction of wi about the normal: ``specular_deg > 2`` leaves out the delta
reflection of a smooth coating, data_formats/layered_models.md); numbers, strings, arithmetic
(+ - * / %), comparisons, and/or/not, parentheses and abs(). Nothing else is evaluated.
"""

from __future__ import annotations

import ast

import numpy as np

from fitlab.errors import FitlabError
from fitlab.io.validate import quote

_ARITH = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply, ast.Div: np.divide,
          ast.Mod: np.mod}
_CMP = {ast.Eq: np.equal, ast.NotEq: np.not_equal, ast.Lt: np.less, ast.LtE: np.less_equal,
        ast.Gt: np.greater, ast.GtE: np.greater_equal}


def _specular_deg(wi, wo):
    """Angle (degrees) between wo and the mirror direction (-wi_x, -wi_y, wi_z)."""
    mirror = np.asarray(wi, dtype=float) * np.array([-1.0, -1.0, 1.0])
    wo = np.asarray(wo, dtype=float)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(mirror, wo), axis=-1),
                                 np.sum(mirror * wo, axis=-1)))


#: Longest expression accepted.
MAX_EXPRESSION = 2000


def rows_of(subset, measurement) -> tuple[str | None, np.ndarray]:
    """(the expression or None, the boolean mask of the fitted rows) of a fit's ``subset``: an
    expression (:func:`subset_mask`), a boolean mask of the measurement's rows, or None (every
    row). The one check fit, compare and fit_many share."""
    n = measurement.n
    if isinstance(subset, str):
        return subset, subset_mask(subset, measurement)
    if subset is None:
        return None, np.ones(n, dtype=bool)
    mask = np.asarray(subset, dtype=bool)
    if mask.shape != (n,):
        raise FitlabError(f"subset: a mask of {n} rows is needed, got shape {mask.shape}")
    return None, mask


def channel_ids(channels, measurement, what: str = "channel") -> list[int] | None:
    """The indices of the named channels (a name or a list of names; None: None, every
    channel), each checked against the measurement's (``what`` names the argument in the
    message)."""
    if channels is None:
        return None
    channels = [channels] if isinstance(channels, str) else list(channels)
    unknown = [c for c in channels if c not in measurement.channel_names]
    if unknown:
        raise FitlabError(f"{what} {', '.join(unknown)}: {measurement.path} has channels "
                          f"{', '.join(measurement.channel_names)}")
    return [measurement.channel_names.index(c) for c in channels]


def subset_mask(expr: str, measurement, source: str = "--fit-subset") -> np.ndarray:
    """Rows of ``measurement`` the expression selects. ``source`` names where the expression
    came from in messages (the option, or a parameter file's field)."""
    if not isinstance(expr, str) or len(expr) > MAX_EXPRESSION:
        raise FitlabError(f"{source}: the expression must be text of at most {MAX_EXPRESSION} "
                          "characters")
    try:
        return _evaluate(expr, measurement, source)
    except (RecursionError, MemoryError, OverflowError, ValueError, TypeError) as exc:
        raise FitlabError(f"{source} {quote(expr)} cannot be evaluated ({type(exc).__name__}); "
                          "example: 'theta_i == 0 and theta_o > 90'") from None


def _evaluate(expr: str, measurement, source: str) -> np.ndarray:
    try:
        tree = ast.parse(expr, mode="eval")
    except SyntaxError as exc:
        raise FitlabError(f"{source} {quote(expr)} is not a valid expression ({exc.msg}); "
                          "example: 'theta_i == 0 and theta_o > 90'") from None
    m = measurement
    names = {"theta_i": m.theta_i, "phi_i": m.phi_i, "theta_o": m.theta_o, "phi_o": m.phi_o,
             "value": m.value, "channel": np.asarray(m.channel_names, dtype=object)[m.channel],
             "row": np.arange(m.n), "specular_deg": _specular_deg(m.wi, m.wo)}
    if m.sigma is not None:
        names["sigma"] = m.sigma  # e.g. 'sigma < 0.2 * value': rows of a well-measured value

    def ev(node):
        if isinstance(node, ast.Expression):
            return ev(node.body)
        if isinstance(node, ast.BoolOp):
            vals = [np.asarray(ev(v), dtype=bool) for v in node.values]
            op = np.logical_and if isinstance(node.op, ast.And) else np.logical_or
            out = vals[0]
            for v in vals[1:]:
                out = op(out, v)
            return out
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
            return ~np.asarray(ev(node.operand), dtype=bool)
        if isinstance(node, ast.BinOp) and type(node.op) in _ARITH:
            return _ARITH[type(node.op)](ev(node.left), ev(node.right))
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            return -ev(node.operand)
        if isinstance(node, ast.Compare):
            left = ev(node.left)
            out = None
            for op, right_node in zip(node.ops, node.comparators):
                right = ev(right_node)
                if type(op) not in _CMP:
                    raise FitlabError(f"{source}: operator not allowed in {quote(expr)}")
                r = _CMP[type(op)](left, right)
                out = r if out is None else out & r
                left = right
            return out
        if isinstance(node, ast.Name):
            if node.id not in names:
                raise FitlabError(f"{source}: unknown name {quote(node.id)}; use "
                                  f"{', '.join(names)}")
            return names[node.id]
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float, str)):
            return node.value
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                and node.func.id == "abs" and len(node.args) == 1 and not node.keywords):
            return np.abs(ev(node.args[0]))
        raise FitlabError(f"{source}: {quote(ast.unparse(node))} is not allowed; use column "
                          "names, numbers, + - * / %, comparisons, and/or/not and abs()")

    mask = np.broadcast_to(np.asarray(ev(tree), dtype=bool), (m.n,)).copy()
    if not mask.any():
        raise FitlabError(f"{source} {quote(expr)} selects no rows of {m.path}")
    return mask
