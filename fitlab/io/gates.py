"""Sanity gates: checks that stop a measurement that is valid but implausible (angles that look
like radians, values that look like another quantity, negative values beyond detector noise, a
stored total integrated scatter the data disagree with). Each gate refuses the file with an
InputFileError (exit status 2) that names the file and the fix, unless it is accepted by name
(``--accept NAME``, ``accept=[NAME]``). ``fitlab info`` reports what every gate finds instead of
refusing. The rules, stated once here, are documented in data_formats/measurement_csv.md,
"Sanity gates".

The read options (``--angles``, ``--accept``, ``--quantity``; ``fitlab.read(path, angles=,
accept=, quantity=)``) are checked by :func:`read_options`. Plain NumPy: this is I/O.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from fitlab.errors import FitlabError, InputFileError
from fitlab.registry import Registry

#: What a measurement's values are: the CSV's ``# quantity:`` line and ``--quantity`` alike.
#: ``bsdf``: f in 1/sr; ``bsdf_cos``: f·|cos θo|; ``radiance_factor``: π·f (a reflectance
#: factor: 1 for a white Lambertian surface); ``relative``: f up to an unknown scale.
QUANTITIES = ("bsdf", "bsdf_cos", "radiance_factor", "relative")
#: Units of a file's angles (``--angles``): radians are converted to degrees on reading.
ANGLES = ("degrees", "radians")

# ---- the stated rules (data_formats/measurement_csv.md, "Sanity gates") --------------------

#: radians: at least this many rows, every θ and φ within [0, π] and [-2π, 2π], some θ > 0 and
#: some θ not a whole number of degrees.
RADIANS_MIN_ROWS = 5
#: quantity: a group (channel, incidence, side) counts with at least this many rows, all
#: values > 0, whose |cos θo| spans at least this factor (largest / smallest).
QUANTITY_MIN_ROWS = 6
QUANTITY_COS_SPAN = 3.0
#: "flat": the standard deviation of ln(value) at most this (about ±5 %); "not flat": at least
#: QUANTITY_STEEP times it.
QUANTITY_FLAT = 0.05
QUANTITY_STEEP = 3.0
#: quantity: a flat f (a diffuse surface) above this many times 1/π reflects more than it
#: receives (albedo π·f > 1).
DIFFUSE_LIMIT = 1.1
#: negative (per channel): a value more than NEGATIVE_SIGMAS sigma below 0 (where sigma is
#: given), or below -NEGATIVE_OF_MAX × the channel's largest value, or more than
#: NEGATIVE_SHARE of the channel's rows negative.
NEGATIVE_SIGMAS = 5.0
NEGATIVE_OF_MAX = 0.05
NEGATIVE_SHARE = 0.10
#: tis: a block's integral of f·cos θo over the file's grid, I, against its stored TIS, T: the
#: grid holds at most the total and, of a grid covering a fraction c of the projected
#: hemisphere, at least about c of it; refused when I > (1 + TIS_TOLERANCE)·T or
#: I < (c - TIS_TOLERANCE)·T.
TIS_TOLERANCE = 0.5


class Finding(NamedTuple):
    """What a gate found in a measurement. ``tripped``: beyond its rule (the file is refused
    unless the gate is accepted); otherwise ``message`` says what it saw within the rule."""

    gate: str
    tripped: bool
    message: str
    fix: str = ""


class Gate(NamedTuple):
    name: str
    #: what it catches, a few words (``--accept`` help, ``fitlab info``)
    title: str
    #: the stated rule, one sentence
    rule: str
    #: check(m, format_name) -> Finding | None (None: the gate does not apply)
    check: Callable


class TisBlock(NamedTuple):
    """One block of a format that stores a total integrated scatter (Zemax's TIS lines, pgII's
    front_integral): the stored value, the integral of the file's values (f·cos θo) over its
    grid and the fraction of the projected hemisphere the grid covers."""

    label: str
    stored: float
    integral: float
    coverage: float


class ReadOptions(NamedTuple):
    """How to read a measurement: its angles' unit, the gates accepted, the quantity that
    overrides the file's (:func:`read_options` checks them)."""

    angles: str = "degrees"
    accept: tuple = ()
    quantity: str | None = None

    def record(self) -> dict:
        """The options that differ from the defaults, as plain values (a fit's parameter file
        records them as ``data.read_options``, so the report reads the file the same way)."""
        out = {}
        if self.angles != "degrees":
            out["angles"] = self.angles
        if self.accept:
            out["accept"] = list(self.accept)
        if self.quantity is not None:
            out["quantity"] = self.quantity
        return out


def read_options(angles=None, accept=(), quantity=None) -> ReadOptions:
    """The read options checked: ``angles`` one of ANGLES (None: degrees), ``accept`` gate
    names (one name or several), ``quantity`` one of QUANTITIES or None (the file's);
    FitlabError naming the first that is not."""
    if angles is None:
        angles = "degrees"
    if angles not in ANGLES:
        raise FitlabError(f"angles {angles!r}: use one of {', '.join(ANGLES)}")
    if quantity is not None and quantity not in QUANTITIES:
        raise FitlabError(f"quantity {quantity!r}: use one of {', '.join(QUANTITIES)}")
    names = (accept,) if isinstance(accept, str) else tuple(accept or ())
    for name in names:
        if not isinstance(name, str) or name not in GATES:
            raise FitlabError(f"accept: {GATES.unknown(name)}")
    return ReadOptions(angles, tuple(dict.fromkeys(names)), quantity)


def _fix(format_name, text: str) -> str:
    """``text`` if the format takes --angles and --quantity (fitlab's CSV), else ''."""
    return text if format_name in (None, "csv") else ""


# ---- radians ---------------------------------------------------------------------------------


def radians_finding(theta, phi, format_name="csv") -> Finding | None:
    """The radians gate on a file's angles (degrees as read; θ of both directions, φ of both):
    a tripped Finding when they look like radians, None otherwise."""
    theta, phi = np.asarray(theta, dtype=np.float64), np.asarray(phi, dtype=np.float64)
    if not (theta.size // 2 >= RADIANS_MIN_ROWS and np.all(np.abs(theta) <= np.pi)
            and np.any(theta > 0) and np.all(np.abs(phi) <= 2 * np.pi)
            and np.any(theta != np.round(theta))):
        return None
    how = _fix(format_name, "read them as radians with --angles radians (Python: "
               "angles='radians'), or convert them to degrees (× 180/π)") or \
        f"convert them to degrees (× 180/π): the {format_name} format states degrees"
    return Finding("radians", True, f"every angle is within [0, π] (θ up to {theta.max():.4g}) "
                   "and not whole degrees: they look like radians, but fitlab reads degrees",
                   f"{how}; if they are degrees, all within 3.1° of the normal, give --accept "
                   "radians")


def _radians(m, format_name):
    return radians_finding(np.concatenate([m.theta_i, m.theta_o]),
                           np.concatenate([m.phi_i, m.phi_o]), format_name) \
        or Finding("radians", False, "the angles do not look like radians")


# ---- quantity --------------------------------------------------------------------------------


def _declared(file_quantity: str) -> tuple[bool, bool]:
    """(relative, values carry |cos θo|) of what the file states (Measurement.file_quantity:
    'bsdf', 'bsdf_cos', 'radiance_factor', 'relative (bsdf_cos)', 'bsdf_cos (tabulated ...)')."""
    s = file_quantity.strip()
    relative = s.startswith("relative")
    if relative:
        s = s[len("relative"):].strip(" ()")
    word = s.split()[0] if s.split() else ""
    return relative, word == "bsdf_cos"


def _groups(m):
    """Row indices of each (channel, incidence, side of the surface) group, and the side (True:
    reflection) of every row."""
    side = (m.wi[:, 2] * m.wo[:, 2]) > 0
    key = np.column_stack([m.channel, np.round(m.wi, 9) + 0.0, side])
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    order = np.argsort(inverse, kind="stable")
    return np.split(order, np.flatnonzero(np.diff(inverse[order])) + 1), side


def _range(levels) -> str:
    lo, hi = min(levels), max(levels)
    return f"{lo:.3g}" if f"{lo:.3g}" == f"{hi:.3g}" else f"{lo:.3g} to {hi:.3g}"


def _quantity(m, format_name):
    relative, with_cos = _declared(m.file_quantity)
    groups, side = _groups(m)
    cos_o = np.abs(m.wo[:, 2])
    checked = other_flat = diffuse = 0
    least_alt = np.inf
    levels = []
    for g in groups:
        v, c = m.value[g], cos_o[g]
        if len(g) < QUANTITY_MIN_ROWS or np.any(v <= 0) or c.min() <= 0 \
                or c.max() / c.min() < QUANTITY_COS_SPAN:
            continue
        s_decl = float(np.std(np.log(v)))
        s_alt = float(np.std(np.log(v * c if with_cos else v / c)))
        checked += 1
        least_alt = min(least_alt, s_alt)
        if s_alt <= QUANTITY_FLAT and s_decl >= QUANTITY_STEEP * QUANTITY_FLAT:
            other_flat += 1
        if not relative and side[g[0]] and s_decl <= QUANTITY_FLAT:
            diffuse += 1
            levels.append(float(np.exp(np.mean(np.log(v)))))
    if not checked:
        return Finding("quantity", False, f"not checked: no incidence has {QUANTITY_MIN_ROWS} or "
                       f"more positive values over a range of |cos θo| of {QUANTITY_COS_SPAN:g}:1")
    said = f"'# quantity: {m.file_quantity}'" if format_name in (None, "csv") and not relative \
        else f"the file states {m.file_quantity}"
    accept = "if the file is right, give --accept quantity"
    if other_flat == checked:
        if with_cos:
            what = ("read as f (divided by |cos θo|) they rise as 1/|cos θo| toward grazing, "
                    "but as written they are flat")
            looks, word = "f itself", "bsdf"
        else:
            what = "the values fall off as |cos θo|: divided by it they are flat"
            looks, word = "f·|cos θo|", "bsdf_cos"
        fix = (f"if so, write '# relative_to: {word}'" if relative else
               f"if so, write '# quantity: {word}'" + _fix(format_name, f" or give --quantity "
                                                          f"{word}"))
        return Finding("quantity", True, f"{said}, but {what} (within {QUANTITY_FLAT:.0%}) at "
                       f"every incidence: they look like {looks}", f"{fix}; {accept}")
    if diffuse and diffuse == checked and min(levels) > DIFFUSE_LIMIT / np.pi:
        fix = "if so, write '# quantity: radiance_factor'" + _fix(
            format_name, " or give --quantity radiance_factor")
        return Finding("quantity", True, f"{said}, but f is flat at {_range(levels)}/sr, above "
                       "1/π ≈ 0.318, the most a diffuse surface reflects (albedo 1): the values "
                       "look like π·f, a radiance or reflectance factor", f"{fix}; {accept}")
    other = "f" if with_cos else "f·|cos θo|"
    if other_flat:
        return Finding("quantity", False, f"{m.file_quantity} fits {checked - other_flat} of "
                       f"{checked} incidences checked (per channel and side)")
    return Finding("quantity", False, f"{m.file_quantity} fits: read as {other} instead, the "
                   f"values are not flat at any of {checked} incidences checked (per channel and "
                   f"side; spread of ln at least {least_alt:.2g})")


# ---- negative --------------------------------------------------------------------------------


def _negative(m, format_name):
    if not np.any(m.value < 0):
        return Finding("negative", False, "no negative value")
    beyond, seen = None, []
    for c, name in enumerate(m.channel_names):
        rows = np.flatnonzero(m.channel == c)
        v = m.value[rows]
        n_neg = int(np.sum(v < 0))
        if not n_neg:
            continue
        top, j = float(v.max()), int(np.argmin(v))
        share = n_neg / v.size
        ch = f"channel {name}: " if len(m.channel_names) > 1 else ""
        depth = f"{-v[j] / top:.2%} of the largest value" if top > 0 else f"{v[j]:.3g}"
        seen.append(f"{ch}{n_neg} negative ({share:.2%} of the rows; the lowest {depth})")
        line = int(m.lines[rows[j]]) if rows[j] < len(m.lines) else None
        at = f" (line {line})" if line is not None else ""
        why = None
        if m.sigma is not None:
            z = v / m.sigma[rows]
            k = int(np.argmin(z))
            if z[k] < -NEGATIVE_SIGMAS:
                kl = int(m.lines[rows[k]]) if rows[k] < len(m.lines) else None
                why = (f"{v[k]:.3g}{f' (line {kl})' if kl is not None else ''} is "
                       f"{-z[k]:.1f} sigma below 0 (the rule: {NEGATIVE_SIGMAS:g})")
        if why is None and top <= 0:
            why = f"no value is positive ({n_neg} negative)"
        elif why is None and v[j] < -NEGATIVE_OF_MAX * top:
            why = (f"{v[j]:.3g}{at} lies {-v[j] / top:.0%} of the largest value ({top:.3g}) "
                   f"below 0 (the rule: {NEGATIVE_OF_MAX:.0%})")
        elif why is None and share > NEGATIVE_SHARE:
            why = (f"{n_neg} of {v.size} rows ({share:.0%}) are negative (the rule: "
                   f"{NEGATIVE_SHARE:.0%})")
        if why is not None and beyond is None:
            beyond = ch + why
    if beyond is not None:
        return Finding("negative", True, f"{beyond}: beyond detector noise",
                       "subtract the right dark level or fix the sign of the values; if the "
                       "data are right, give --accept negative")
    return Finding("negative", False, "; ".join(seen) + ": within detector noise")


# ---- tis -------------------------------------------------------------------------------------


def _tis(m, format_name):
    blocks = [b for b in m.tis_blocks if b.stored > 0]
    if not blocks:
        return None
    bad, worst = None, 0.0
    for b in blocks:
        ratio = b.integral / b.stored
        worst = max(worst, abs(ratio - 1.0))
        if bad is None and (ratio > 1 + TIS_TOLERANCE or ratio < b.coverage - TIS_TOLERANCE):
            bad = b
    if bad is None:
        return Finding("tis", False, "the data's integral of f·cos θo is within "
                       f"{worst:.1%} of the stored TIS in every block ({len(blocks)})")
    ratio = bad.integral / bad.stored
    return Finding("tis", True, f"{bad.label}: the data integrate to {bad.integral:.4g} "
                   f"(f·cos θo over the grid, which covers {bad.coverage:.0%} of the projected hemisphere) "
                   f"but the stored TIS is {bad.stored:.4g} ({ratio - 1:+.0%}; the rule allows "
                   f"{max(bad.coverage - TIS_TOLERANCE, 0):.0%} to {1 + TIS_TOLERANCE:.0%} of it)",
                   "check the file's units, angles and scatter type against its source (a "
                   "BTDF's angles are about the refracted ray: give the refractive indices); "
                   "if the data are right, give --accept tis")


GATES: Registry[Gate] = Registry("sanity gate", {
    "radians": Gate("radians", "angles that look like radians",
                    "every θ and φ within [0, π] and [-2π, 2π], some θ not a whole degree, "
                    f"at least {RADIANS_MIN_ROWS} rows", _radians),
    "quantity": Gate("quantity", "values that look like another quantity",
                     "at every incidence, the values read the other way (f with or without "
                     "|cos θo|) are flat while the file's reading is not; or a flat f above "
                     f"{DIFFUSE_LIMIT:g}/π", _quantity),
    "negative": Gate("negative", "negative values beyond detector noise",
                     f"a value more than {NEGATIVE_SIGMAS:g} sigma or {NEGATIVE_OF_MAX:.0%} of "
                     f"its channel's largest value below 0, or more than {NEGATIVE_SHARE:.0%} of "
                     "a channel's rows negative", _negative),
    "tis": Gate("tis", "a stored total integrated scatter the data disagree with",
                "a block's integral of f·cos θo over the grid above "
                f"{1 + TIS_TOLERANCE:g} times the stored TIS, or below (coverage - "
                f"{TIS_TOLERANCE:g}) times it", _tis),
}, listing="data_formats/measurement_csv.md, 'Sanity gates'")


def findings(m, format_name: str | None = None) -> list[Finding]:
    """What every gate that applies to ``m`` finds (tripped or not)."""
    out = []
    for gate in GATES.values():
        f = gate.check(m, format_name)
        if f is not None:
            out.append(f)
    return out


def apply_gates(m, format_name: str | None, options: ReadOptions, *, enforce: bool = True):
    """``m`` if no gate trips beyond what ``options.accept`` accepts, recording the accepted
    findings (``m.accepted``) and the options (``m.read_options``); otherwise (with
    ``enforce``) the InputFileError of the first gate that trips, naming the file and the fix."""
    found = [f for f in findings(m, format_name) if f.tripped]
    refused = [f for f in found if f.gate not in options.accept]
    if enforce and refused:
        first = refused[0]
        more = [f.gate for f in refused[1:]]
        also = (f" (it also trips {', '.join(more)}; `fitlab info` lists every gate's finding)"
                if more else "")
        raise gate_error(m.path, first, also)
    accepted = tuple(f"{f.gate}: {f.message}" for f in found if f.gate in options.accept)
    return m._replace(accepted=accepted, read_options=options.record() or None)


def gate_error(path, finding: Finding, also: str = "") -> InputFileError:
    return InputFileError(path, f"sanity gate {finding.gate!r}: {finding.message}{also}",
                          hint=finding.fix)


def notes(m) -> list[str]:
    """Sentences for a fit's notes and the commands' output: how the file was read, where that
    differs from the defaults, and each gate accepted by override."""
    out = []
    opts = m.read_options or {}
    if opts.get("angles") == "radians":
        out.append(f"{m.path}: angles read as radians (--angles radians), converted to degrees")
    if opts.get("quantity"):
        out.append(f"{m.path}: values read as {opts['quantity']} (declared by --quantity)")
    out += [f"{m.path}: accepted by --accept {a.split(':', 1)[0]}: {a.split(': ', 1)[1]}"
            for a in m.accepted]
    return out


def summary(m, format_name: str | None, accept=()) -> tuple[list[str], dict]:
    """(warnings, gates) for ``fitlab info``: a sentence for every gate that trips (refused by
    the commands that read the file, or accepted by --accept), and each gate's finding."""
    warnings, gates = [], {}
    for f in findings(m, format_name):
        if not f.tripped:
            gates[f.gate] = f"passes: {f.message}"
        elif f.gate in accept:
            gates[f.gate] = f"accepted (--accept {f.gate}): {f.message}"
            warnings.append(f"{f.gate} (accepted by --accept {f.gate}): {f.message}")
        else:
            gates[f.gate] = f"REFUSES: {f.message}"
            warnings.append(f"{f.gate}: {f.message}; fit, convert, compare and report refuse "
                            f"the file: {f.fix}")
    return warnings, gates


__all__ = ["ANGLES", "GATES", "QUANTITIES", "Finding", "Gate", "ReadOptions", "TisBlock",
           "apply_gates", "findings", "gate_error", "notes", "radians_finding", "read_options",
           "summary"]
