"""The fit's model check: a layered model against the Monte Carlo simulation of its own fitted
stack (``Model.scene_of``), at the data's fitted directions, so that a user sees whether a
misfit is the data's (or the model family's) or the model's approximation of its stack.

After a channel is fitted, :func:`check_channel` simulates the fitted stack
(:mod:`fitlab.simulate.model_stack`: every bounce and scattering order traced) at the
channel's fitted rows (at most :data:`MAX_ROWS`, an evenly spaced subset beyond), with the
paths per incidence chosen from a pilot run so that the RMS relative standard error over the
rows that count reaches :data:`TARGET_SE`, and scores the model against it by the fit error's
own definition (:func:`fitlab.metrics.fit_error`), the fit's error beside it.

``mode`` (``FitRequest.check_model``, ``fitlab fit --check-model``): ``auto`` runs the check
where its cost, estimated from the pilot, is at most max(:data:`BUDGET_FRACTION` × the fit's
time so far, :data:`MIN_BUDGET_S`), else records why it skipped it; ``on`` always runs it;
``off`` never does. A model that is not layered (no stack, or a single interface or bare
substrate: :func:`fitlab.simulate.model_stack.is_layered`) is ``not_applicable``.

The record (the parameter file's ``fits[k].model_check``, data_formats/fit_json.md) holds no
wall-clock time (the parameter file is byte-identical run to run; the seconds go to
``timings_s``), but ``auto``'s choice depends on the machine's speed: give ``on`` or ``off``
for a file that must not.
"""

from __future__ import annotations

import contextlib
import time

import numpy as np

from fitlab.metrics import fit_error, incidence_floor_mask, incidence_groups

#: FitRequest.check_model's values.
MODES = ("auto", "on", "off")
#: The RMS relative standard error the simulation must reach, and what the sample count aims
#: at (a margin for the pilot's own scatter in its estimate of the error).
TARGET_SE = 0.02
AIM_SE = 0.85 * TARGET_SE
#: auto: the check runs where its estimated cost is at most max(fraction × fit time, floor).
BUDGET_FRACTION = 0.2
MIN_BUDGET_S = 10.0
#: Paths per incidence of the compiling warm-up run and of the timed pilot run.
WARMUP_SAMPLES = 64
PILOT_SAMPLES = 500
#: The bounds of the chosen paths per incidence.
MIN_SAMPLES = 1_000
MAX_SAMPLES = 1_000_000
#: At most this many fitted rows are simulated (an evenly spaced subset of them beyond).
MAX_ROWS = 4_000


def record_of(status: str, reason: str, **fields) -> dict:
    """A model-check record: ``status`` run / skipped / not_applicable and the sentence why."""
    return {"status": status, "reason": reason, **fields}


def applicable(model, params: dict, options: dict):
    """(scene, status, reason): the scene where ``model`` at ``params`` is a layered stack the
    simulator traces (status None), else None, ``not_applicable`` (no stack, or not layered)
    or ``skipped`` (a layered stack at values the simulator cannot express) and why."""
    from fitlab.simulate.model_stack import is_layered, stack_scene

    if getattr(model, "scene_of", None) is None:
        return None, "not_applicable", f"{model.name} names no layer stack for the simulator"
    try:
        scene = stack_scene(model, params, options)
    except ValueError as exc:
        return None, "skipped", f"the fitted stack cannot be simulated: {exc}"
    if not is_layered(scene):
        return None, "not_applicable", (f"{model.name} is not layered (a single interface or "
                                        "substrate: the simulator's stack is the model itself)")
    return scene, None, None


def row_subset(index: np.ndarray, cap: int = MAX_ROWS) -> np.ndarray:
    """``index`` (row numbers), or ``cap`` of them evenly spaced where there are more."""
    if index.size <= cap:
        return index
    return index[np.unique(np.round(np.linspace(0, index.size - 1, cap)).astype(int))]


def relative_se(result) -> tuple[float, np.ndarray]:
    """The RMS relative standard error of a one-channel simulation over its rows that count
    (the fit error's floor rule on the simulated values), and that mask."""
    v, s = result.value[:, 0], result.sigma[:, 0]
    keep = incidence_floor_mask(np.abs(v), incidence_groups(result.theta_i, result.phi_i)) & (
        v > 0)
    rel = s[keep] / v[keep]
    return (float(np.sqrt(np.mean(rel ** 2))) if rel.size else float("inf")), keep


def samples_for(pilot_se: float, pilot: int = PILOT_SAMPLES, target: float = TARGET_SE,
                most: int = MAX_SAMPLES) -> int:
    """Paths per incidence that bring the pilot's RMS relative standard error to ``target``
    (the error falls as 1/√N), within [MIN_SAMPLES, ``most``]."""
    if not np.isfinite(pilot_se):
        return most
    need = int(np.ceil(pilot * (pilot_se / target) ** 2))
    return int(min(max(need, MIN_SAMPLES), most))


def budget_s(fit_seconds: float, min_budget_s: float = MIN_BUDGET_S) -> float:
    """auto's budget: max(BUDGET_FRACTION × the fit's seconds, ``min_budget_s``)."""
    return max(BUDGET_FRACTION * fit_seconds, min_budget_s)


def check_channel(model, params: dict, options: dict, rows, fit_rms, *, mode: str = "auto",
                  fit_seconds: float = 0.0, seed: int = 0, min_budget_s: float = MIN_BUDGET_S,
                  log=lambda msg: None) -> tuple[dict, float]:
    """The model check of one fitted channel: ``model`` at ``params`` (its parameters, no
    scale) and ``options`` against its simulated stack at the directions of Measurement
    ``rows`` (the channel's fitted rows); ``fit_rms``: the fit's own RMS relative error, put
    beside the model's. Returns (the record, seconds spent)."""
    t0 = time.perf_counter()
    scene, status, why = applicable(model, params, options)
    if scene is None:
        return record_of(status, why, **({"fit_error": fit_rms} if status == "skipped"
                                         else {})), 0.0
    if mode == "off":
        return record_of("skipped", "check_model off (--check-model off)",
                         fit_error=fit_rms), 0.0
    from fitlab.errors import InputFileError
    from fitlab.fitting.space import model_values
    from fitlab.simulate import simulate
    from fitlab.simulate.model_stack import model_at_rows, rows_scene

    index = row_subset(np.arange(rows.n))
    sub = rows.take(index)
    subset = (f"{index.size} of the {rows.n} fitted rows, evenly spaced"
              if index.size < rows.n else f"all {rows.n} fitted rows")
    with contextlib.ExitStack() as stack:  # one scene (the rows' file) for all three runs
        try:
            sc = stack.enter_context(rows_scene(scene, sub))
            simulate(sc, WARMUP_SAMPLES, seed)  # compiles
            t1 = time.perf_counter()
            pilot = simulate(sc, PILOT_SAMPLES, seed)
            t_pilot = time.perf_counter() - t1
        except (InputFileError, ValueError) as exc:
            return record_of("skipped", f"the simulator refused the stack or the rows: {exc}",
                             fit_error=fit_rms), time.perf_counter() - t0
        pilot_se, _ = relative_se(pilot)
        n = samples_for(pilot_se, target=AIM_SE)
        estimate = t_pilot * n / PILOT_SAMPLES
        budget = budget_s(fit_seconds, min_budget_s)
        if mode == "auto" and estimate > budget:
            return record_of(
                "skipped", f"auto: estimated {estimate:.3g} s for {n:,} paths per incidence "
                f"(pilot relative SE {pilot_se:.3g}) is over the budget {budget:.3g} s (max of "
                f"{BUDGET_FRACTION:g} x the fit's {fit_seconds:.3g} s and {min_budget_s:g} s); "
                "--check-model on runs it", rows=int(index.size), samples=n,
                fit_error=fit_rms), time.perf_counter() - t0
        log(f"  model check: simulating the fitted stack at {subset}, {n:,} paths per "
            f"incidence (estimated {estimate:.2g} s)")
        sim = simulate(sc, n, seed)
    se, _ = relative_se(sim)
    mm = sim.to_measurement()
    opts = tuple(sorted(options.items()))
    pred = model_at_rows(lambda wi, wo: np.asarray(
        model_values(model, opts, params, wi, wo), float)[:, None], mm)[:, 0]
    err = fit_error(pred, mm.value, mm.theta_i, mm.phi_i)
    rec = record_of(
        "run", f"{'on' if mode == 'on' else 'auto'}: {subset}; paths per incidence for a "
        f"relative SE of at most {TARGET_SE:g}, aimed at {AIM_SE:.2g} (pilot of "
        f"{PILOT_SAMPLES} paths: {pilot_se:.3g})",
        rows=int(index.size), samples=n, relative_se=se if np.isfinite(se) else None,
        estimator=sim.scene.detector.estimator,
        model_error=err["rms_relative_error"], model_error_rows=err["rows"],
        fit_error=fit_rms, per_incidence=[
            {"theta_i": r["theta_i"], "phi_i": r["phi_i"],
             "model_error": r["rms_relative_error"]} for r in err["per_incidence"]])
    return rec, time.perf_counter() - t0


def check_fit(m, results: list, rows_fit: np.ndarray, *, mode: str, fit_seconds: float,
              seed: int = 0, log=lambda msg: None) -> None:
    """Add ``model_check`` (the record) and ``seconds_model_check`` to each fitted channel of
    ``results`` (fit_measurement's channel dicts) of Measurement ``m``; ``fit_seconds``: the
    fit's time so far (auto's budget), each check's own time added for the next channel."""
    from fitlab.fitting.space import SCALE

    for ch in results:
        space, ls = ch["space"], ch["ls"]
        params = {**space.fixed, **{k: float(v) for k, v in zip(space.names, ls.native)
                                    if k != SCALE}}
        index = ch["rows"][rows_fit[ch["rows"]]]
        fe = (ch["statistics"].get("fit_error") or {}).get("rms_relative_error")
        rec, secs = check_channel(space.model, params, space.options, m.take(index), fe,
                                  mode=mode, fit_seconds=fit_seconds, seed=seed, log=log)
        fit_seconds += secs
        ch["model_check"] = None if rec["status"] == "not_applicable" else rec
        ch["seconds_model_check"] = secs


def check_line(channel: str, rec: dict | None) -> str | None:
    """The terminal's line of a channel's model check ("model vs its own stack: X%; fit vs
    data: Y%"), or the reason it was skipped; None where it does not apply or is absent."""
    if not rec or rec["status"] == "not_applicable":
        return None
    if rec["status"] == "skipped":
        return f"model check of channel {channel} skipped: {rec['reason']}"
    me, fe = rec.get("model_error"), rec.get("fit_error")
    pct = (lambda x: "n/a" if x is None else f"{100 * x:.3g}%")
    return (f"channel {channel}: model vs its own stack: {pct(me)}; fit vs data: {pct(fe)} "
            f"(simulated at {rec['rows']} rows, {rec['samples']:,} paths per incidence, "
            f"relative SE {_num(rec.get('relative_se'))})")


def check_text(rec: dict | None) -> str | None:
    """The model check as the report's sentences: the two errors side by side and what they
    say, or why it was skipped; None where it does not apply or is absent."""
    if not rec or rec["status"] == "not_applicable":
        return None
    if rec["status"] == "skipped":
        return f"Model check skipped: {rec['reason']}."
    return (f"Model check: the model against the Monte Carlo simulation of its own fitted stack "
            f"at {rec['rows']} fitted rows ({rec['samples']:,} paths per incidence, relative "
            f"standard error {_num(rec.get('relative_se'))}): RMS relative error "
            f"{_num4(rec.get('model_error'))}, beside the fit's {_num4(rec.get('fit_error'))} "
            f"against the data (the same definition). {interpretation(rec) or ''}").rstrip()


def _num4(x) -> str:
    return "n/a" if x is None else f"{x:.4g}"


def _num(x) -> str:
    return "n/a" if x is None else f"{x:.2g}"


def interpretation(rec: dict) -> str | None:
    """One sentence on what the two errors say (report, terminal -v)."""
    if not rec or rec.get("status") != "run":
        return None
    me, fe = rec.get("model_error"), rec.get("fit_error")
    if me is None or fe is None:
        return None
    if me < 0.3 * fe:
        return ("The model reproduces its own stack far better than it fits the data: the "
                "misfit is the data's or the model family's, not the approximation's.")
    return ("The model's error against its own stack is comparable to the fit's: its "
            "approximation of the stack limits the fit.")


__all__ = ["AIM_SE", "MODES", "TARGET_SE", "check_channel", "check_fit", "check_line",
           "check_text", "interpretation",
           "record_of", "samples_for"]
