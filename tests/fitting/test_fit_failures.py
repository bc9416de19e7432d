"""Fits that go wrong say so (issue 12, part 7): a Levenberg–Marquardt run stopped by its
iteration limit and non-finite costs met by the global search are recorded in the parameter
file and warned about; a NaN log-probability in the MCMC is an error naming the point, while
−inf outside the prior stays a rejected move. Also the loss registry (part 4)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from fitlab.export.paramfile import build_record
from fitlab.fitting import least_squares as fls
from fitlab.fitting import mcmc as fmcmc
from fitlab.fitting import searches
from fitlab.fitting.channel import FitWarning
from fitlab.fitting.driver import fit_measurement
from fitlab.fitting.request import FitRequest
from fitlab.fitting.losses import LOSSES, Loss, has_absolute_noise, loss_weights, residuals

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from test_fit import synthetic  # noqa: E402


@pytest.fixture(scope="module")
def oren_nayar_data():
    return synthetic("oren_nayar", {"albedo": 0.6, "sigma": 0.5}, thetas_i=(0, 45),
                     thetas_o=tuple(range(0, 90, 6)), seed=4)


@pytest.fixture
def nan_where_albedo_above(monkeypatch):
    """Make the fit's residuals NaN wherever the first free parameter (albedo) exceeds a
    threshold: a stand-in for a model that is not finite in part of its parameter box. Every
    cached kernel is dropped before and after, so no other test sees the patched residuals."""

    def install(threshold):
        orig = fls.residuals_native

        def patched(static, loss, theta, problem):
            r = orig(static, loss, theta, problem)
            return jnp.where(theta[0] > threshold, jnp.nan, r)

        monkeypatch.setattr(fls, "residuals_native", patched)
        fls.kernels.cache_clear()
        fmcmc.log_posterior_fn.cache_clear()

    yield install
    fls.kernels.cache_clear()
    fmcmc.log_posterior_fn.cache_clear()


def _no_global_search(monkeypatch, u):
    """Replace the global search by a fixed, poor start (so that every LM start has work left)."""

    def fixed_start(search, k, problem, scan_problem, scan_rows, ndim, seed, starts, *args,
                    **kwargs):
        return np.concatenate([np.full((1, ndim), u), searches.halton(starts, ndim)]), {"algorithm": "test stub", "evaluations": 0, "non_finite": 0,
                                  "status": "skipped", "best_cost": None}

    monkeypatch.setattr(fls, "global_start", fixed_start)


# --------------------------------------------------------------------------------------------
# Levenberg–Marquardt at its iteration limit
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_lm_iteration_limit_is_recorded_and_warned(oren_nayar_data, monkeypatch):
    m = oren_nayar_data
    _no_global_search(monkeypatch, 0.05)
    with pytest.warns(FitWarning, match="stopped at its iteration limit \\(2 iterations\\)"):
        res = fit_measurement(m, FitRequest("oren_nayar", starts=2, seed=0, lm_maxiter=2))
    ch = res["channels"][0]
    assert ch["ls"].solver["stopped"] == "max_iterations"
    assert any("iteration limit" in w for w in ch["warnings"])
    rec = json.loads(json.dumps(build_record(res, m), allow_nan=False))
    (fit,) = rec["fits"]
    assert fit["solver"]["stopped"] == "max_iterations"
    assert fit["solver"]["iterations"] == fit["solver"]["max_iterations"] == 2
    assert all(s["lm_iterations"] == 2 and s["lm_stopped"] == "max_iterations"
               for s in fit["starts"])
    assert any(w.startswith("Levenberg-Marquardt stopped at its iteration limit")
               and "--lm-maxiter" in w for w in fit["warnings"])

    # The same fit with the default limit converges, and says nothing about iterations.
    res = fit_measurement(m, FitRequest("oren_nayar", starts=2, seed=0), warn=False)
    fit = build_record(res, m)["fits"][0]
    assert fit["solver"]["stopped"] == "converged"
    assert 2 < fit["solver"]["iterations"] < fit["solver"]["max_iterations"] == fls.LM_MAXITER
    assert not any("iteration limit" in w for w in fit["warnings"])


def test_lm_stop_reason():
    assert fls.lm_stop_reason(1.0, 5, False, 200) == "converged"
    assert fls.lm_stop_reason(1.0, 200, False, 200) == "converged"  # met the rule at the last step
    assert fls.lm_stop_reason(1.0, 200, True, 200) == "max_iterations"
    assert fls.lm_stop_reason(float("nan"), 3, False, 200) == "non_finite"
    assert fls.lm_stop_reason(float("inf"), 200, True, 200) == "non_finite"


# --------------------------------------------------------------------------------------------
# Non-finite costs in the global search
# --------------------------------------------------------------------------------------------


def test_global_search_counts_non_finite_costs():
    """nlopt sees 1e300 where the cost is NaN; the search counts those points exactly."""
    calls = {"n": 0, "bad": 0}

    def cost(u):
        calls["n"] += 1
        if u[0] > 0.7:
            calls["bad"] += 1
            return np.nan, np.full(2, np.nan)
        return float(np.sum((u - 0.3) ** 2)), 2 * (u - 0.3)

    def value_and_grad(u, problem):
        v, g = cost(np.asarray(u))
        return np.concatenate([[v], g])

    def value(u, problem):
        return cost(np.asarray(u))[0]

    u, info = searches.global_search(2, value_and_grad, None, seed=0, maxeval=300, value=value)
    assert info["evaluations"] == calls["n"] > 0
    assert info["non_finite"] == calls["bad"] > 0
    np.testing.assert_allclose(u, 0.3, atol=1e-3)
    assert info["best_cost"] is not None and np.isfinite(info["best_cost"])


def test_scan_counts_non_finite_costs_and_keeps_the_best_point():
    """The scan evaluates every point once, in one call, and counts the NaN costs exactly."""
    seen = []

    def costs_at(U, problem):
        seen.append(U)
        c = np.sum((U - 0.3) ** 2, axis=1)
        return np.where(U[:, 0] > 0.7, np.nan, c)

    best, info = searches.scan_search(2, costs_at, None, seed=0, n_points=300, rows=7, keep=5)
    (U,) = seen
    assert U.shape == (300, 2) and info["evaluations"] == 300 and "7 rows" in info["algorithm"]
    assert info["non_finite"] == int(np.sum(U[:, 0] > 0.7)) > 0
    finite = U[U[:, 0] <= 0.7]
    cost = np.sum((finite - 0.3) ** 2, axis=1)
    np.testing.assert_array_equal(best, finite[np.argsort(cost)[:5]])  # the 5 best, best first
    assert info["best_cost"] == pytest.approx(float(cost.min()))
    # another seed scans another stretch of the sequence
    assert not np.array_equal(searches.scan_points(300, 2, 1), U)
    # nothing finite: the box's centre, said so
    best, info = searches.scan_search(2, lambda U, p: np.full(len(U), np.nan), None, 0, 16, 7)
    assert np.all(best == 0.5) and info["best_cost"] is None and info["non_finite"] == 16


def test_scan_of_many_rows_evaluates_an_even_subset():
    n = searches.SCAN_ROWS * 3 + 5
    data = fls.FitData(np.zeros((n, 3)), np.zeros((n, 3)), np.arange(n, dtype=float),
                       {"c": np.arange(n, dtype=float)})
    sub = fls.scan_rows(_static(rows_fixed=False), data)
    assert sub.value.shape == (searches.SCAN_ROWS,) and sub.value[0] == 0 and sub.value[-1] == n - 1
    np.testing.assert_array_equal(sub.consts["c"], sub.value)  # every field the same rows
    assert np.all(np.diff(sub.value) > 0)
    assert fls.scan_rows(_static(rows_fixed=True), data) is data  # a joint fit scans all
    small = data._replace(value=data.value[:100])
    assert fls.scan_rows(_static(rows_fixed=False), small) is small


def _static(rows_fixed):
    from types import SimpleNamespace

    return SimpleNamespace(rows_fixed=rows_fixed)


@pytest.mark.parametrize("search", ["scan", "mlsl"])
def test_non_finite_costs_are_recorded_and_warned(oren_nayar_data, nan_where_albedo_above,
                                                  search):
    m = oren_nayar_data
    nan_where_albedo_above(0.9)  # truth 0.6: the optimum is still reachable
    with pytest.warns(FitWarning, match="non-finite cost"):
        res = fit_measurement(m, FitRequest("oren_nayar", starts=2, seed=0,
                                            global_search=search))
    fit = json.loads(json.dumps(build_record(res, m), allow_nan=False))["fits"][0]
    g = fit["global_search"]
    assert g["algorithm"].startswith({"scan": "Halton scan", "mlsl": "nlopt"}[search])
    assert 0 < g["non_finite"] < g["evaluations"]
    assert any(f"at {g['non_finite']} of {g['evaluations']} evaluations" in w
               for w in fit["warnings"])
    assert fit["parameters"]["albedo"]["value"] == pytest.approx(0.6, abs=0.05)


def test_clean_fit_has_no_warnings(oren_nayar_data):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", FitWarning)
        res = fit_measurement(oren_nayar_data, FitRequest("oren_nayar", starts=2, seed=0))
    fit = build_record(res, oren_nayar_data)["fits"][0]
    assert fit["global_search"]["non_finite"] == 0
    assert fit["warnings"] == []


# --------------------------------------------------------------------------------------------
# NaN log-probability in the MCMC
# --------------------------------------------------------------------------------------------


def test_mcmc_nan_log_probability_names_the_point(oren_nayar_data, nan_where_albedo_above):
    m = oren_nayar_data
    res = fit_measurement(m, FitRequest("oren_nayar", starts=1, seed=0), warn=False)
    ch = res["channels"][0]
    space, ls = ch["space"], ch["ls"]
    assert space.names[0] == "albedo"
    from fitlab.fitting.channel import prepare_channel

    data = prepare_channel(m, "oren_nayar", rows=np.ones(m.n, bool))["data"]
    threshold = float(ls.native[0])  # the walkers start around it: about half are past it
    nan_where_albedo_above(threshold)

    setup = fmcmc.mcmc_setup(space, data, ch["statistics"]["loss"], ls, seed=0)
    outside = setup["p0"][:2].copy()
    outside[:, 1] = 1.5  # beyond the prior box: −inf, a rejected move, not an error
    assert np.all(setup["log_prob"](outside) == -np.inf)

    with pytest.raises(fmcmc.NaNLogProbabilityError,
                       match=r"log-probability is NaN at albedo=[0-9.e+-]+, sigma=") as exc:
        fmcmc.run_mcmc(space, data, ch["statistics"]["loss"], ls, seed=0, nsteps=50,
                       progress=False)
    assert exc.value.params["albedo"] > threshold
    assert set(exc.value.params) == set(space.names)
    from fitlab.errors import FitlabError

    assert isinstance(exc.value, FitlabError)


# --------------------------------------------------------------------------------------------
# The loss registry (issue 12, part 4)
# --------------------------------------------------------------------------------------------


def test_loss_registry_carries_behaviour():
    assert tuple(LOSSES) == ("chi2", "relative", "log", "cos_l2")
    for name, loss in LOSSES.items():
        assert isinstance(loss, Loss) and loss.name == name and loss.description
        assert has_absolute_noise(name) is loss.absolute_noise
    assert [n for n, loss in LOSSES.items() if loss.absolute_noise] == ["chi2"]
    rng = np.random.default_rng(1)
    v, s, c = rng.random(20) + 0.1, rng.random(20) + 0.1, rng.random(20) - 0.5
    m = jnp.asarray(v * 1.1)
    # Reference formulas of data_formats/fit_json.md, written out here.
    floor = 0.01 * np.max(np.abs(v))
    expect = {
        "chi2": (v * 1.1 - v) / s,
        "relative": (v * 1.1 - v) / np.maximum(np.abs(v), floor),
        "log": np.log1p(v * 1.1 * np.abs(c)) - np.log1p(v * np.abs(c)),
        "cos_l2": (v * 1.1 - v) * np.abs(c),
    }
    for name in LOSSES:
        r = residuals(name, m, jnp.asarray(v), loss_weights(name, v, s, c))
        np.testing.assert_allclose(np.asarray(r), expect[name], rtol=1e-12, atol=1e-15)
    with pytest.raises(ValueError, match="needs a sigma column"):
        loss_weights("chi2", v, None, c)
    with pytest.raises(ValueError, match="unknown loss 'l1'.* Losses: chi2, relative"):
        loss_weights("l1", v, s, c)


# --------------------------------------------------------------------------------------------
# The CLI prints the record's warnings
# --------------------------------------------------------------------------------------------


def test_cli_prints_the_warnings(tmp_path, capsys, nan_where_albedo_above):
    from fitlab.cli import main

    nan_where_albedo_above(0.95)
    data = Path(__file__).resolve().parents[2] / "data_formats" / "examples" / \
        "measurement_rgb_sigma.csv"
    out = tmp_path / "fit.json"
    assert main(["fit", str(data), "--model", "lambertian", "--channel", "R", "-v",
                 "--out", str(out)]) == 0
    err = capsys.readouterr().err
    fit = json.loads(out.read_text())["fits"][0]
    assert fit["global_search"]["non_finite"] > 0 and fit["warnings"]
    for w in fit["warnings"]:
        assert f"warning: channel R: {w}\n" in err
    assert "non-finite cost" in err
    from fitlab.fitting.status import channel_statuses

    for status in channel_statuses(fit):  # what limits trust, with what to do about it
        assert (f"status: channel R: {status.value}: {status.advice}\n" in err) != status.ok


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["fitlab", "jaxopt"])
def test_flat_cost_starts_do_not_poison_the_fit(tmp_path, solver):
    """Beckmann data (issue 13: simulated Beckmann interfaces crashed the fit-file writer):
    starts at α ≲ 1e-3 see a model that is exactly 0 at every measured direction (Beckmann's D
    underflows), so every Jacobian entry is 0. fitlab's solver stops there at once (‖Jᵀr‖∞ = 0
    meets its rule: the start ends where it began, a worse local minimum); jaxopt's first step is
    0/0, and the start ends marked non_finite, with a warning. Either way the fit comes from the
    others and the parameter file is valid JSON. (The global scan's starts lie where the cost is
    lowest, never there: the flat start is the user's ``start``.)"""
    m = synthetic("rough_dielectric", {"alpha": 0.3, "eta": 1.5}, thetas_i=(0.0, 30.0),
                  thetas_o=tuple(range(7, 180, 10)), options={"distribution": "beckmann"})
    res = fit_measurement(m, FitRequest("rough_dielectric", options={"distribution": "beckmann"},
                                        fix={"eta": 1.5}, start={"alpha": 2e-4},
                                        local_solver=solver), warn=False)
    ls = res["channels"][0]["ls"]
    flat = [s for s in ls.starts if s["start"]["alpha"] == pytest.approx(2e-4)]
    assert len(flat) == 1
    if solver == "jaxopt":
        assert flat[0]["lm_stopped"] == "non_finite"
        assert flat[0]["end"] is None and flat[0]["cost"] is None
        assert any("ended at NaN or inf" in w for w in res["channels"][0]["warnings"])
    else:
        assert flat[0]["lm_stopped"] == "converged" and flat[0]["lm_iterations"] == 0
        assert flat[0]["end"] == flat[0]["start"] and flat[0]["cost"] > 10 * ls.cost
    assert ls.native[0] == pytest.approx(0.3, rel=0.02)
    rec = build_record(res, m)
    json.loads(json.dumps(rec, allow_nan=False))  # writable: no NaN anywhere


@pytest.mark.parametrize("edit, fragment", [
    (lambda v: np.where(np.arange(v.size) == 5, 1e308, v), "is beyond ±1e+100"),
    (lambda v: np.zeros_like(v), "is 0: there is nothing to fit"),
])
def test_fits_that_cannot_be_finite_write_nothing(tmp_path, capsys, edit, fragment):
    """Issue 13: one value of 1e308, or all values 0 without sigma, crashed while writing the
    JSON ('Out of range float values'). Now: exit 2, the file named, nothing written."""
    from fitlab.cli import main
    from fitlab.io.measurement import read_measurement

    src = Path(__file__).resolve().parents[2] / "data_formats" / "examples" / "walter_rough_glass.csv"
    m = read_measurement(src)
    lines = src.read_text().splitlines()
    head = [ln for ln in lines if ln.startswith("#")]
    body = ["theta_i,phi_i,theta_o,phi_o,value"] + [
        f"{a:.17g},{b:.17g},{c:.17g},{d:.17g},{v:.17g}" for a, b, c, d, v in
        zip(m.theta_i, m.phi_i, m.theta_o, m.phi_o, edit(m.value))]
    data = tmp_path / "data.csv"
    data.write_text("\n".join(head + body) + "\n")
    out = tmp_path / "fit.json"
    assert main(["fit", str(data), "--model", "rough_dielectric", "--quiet", "--out",
                 str(out)]) == 2
    err = capsys.readouterr().err
    assert str(data) in err and fragment in err and "Traceback" not in err
    assert not out.exists()


def test_fit_whose_cost_overflows_everywhere_writes_nothing(tmp_path, capsys):
    """Valid values with a sigma of 1e-200 make every χ² residual ~1e200 and the cost inf at
    every start: the fit says it reached no finite values, names the file, writes nothing."""
    from fitlab.cli import main

    data = tmp_path / "tiny_sigma.csv"
    rows = [f"{ti},0,{to},180,{0.1 + 0.01 * k},1e-200" for k, (ti, to) in
            enumerate((a, b) for a in (0, 20, 40) for b in (10, 30, 50, 70))]
    data.write_text("# quantity: bsdf\n# scatter: brdf\n"
                    "theta_i,phi_i,theta_o,phi_o,value,sigma\n" + "\n".join(rows) + "\n")
    out = tmp_path / "fit.json"
    assert main(["fit", str(data), "--model", "lambertian", "--quiet", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(data) in err and "did not reach finite values" in err and "Traceback" not in err
    assert not out.exists()


def test_first_non_finite_names_the_field():
    from fitlab.export.paramfile import first_non_finite

    assert first_non_finite({"a": [1.0, {"b": 2.0}], "c": "x"}) is None
    assert first_non_finite({"fits": [{"statistics": {"chi2": float("nan")}}]}) == \
        "fits[0].statistics.chi2"


# --------------------------------------------------------------------------------------------
# Status: one type for what limits trust in a fit (fitlab/fitting/status.py)
# --------------------------------------------------------------------------------------------


def test_status_members_are_the_strings_files_keep():
    from fitlab.fitting.status import Status

    assert json.dumps({"stopped": Status.MAX_ITERATIONS}) == '{"stopped": "max_iterations"}'
    assert Status("non_finite") is Status.NON_FINITE and f"{Status.CONVERGED}" == "converged"
    assert [s for s in Status if s.ok] == [Status.CONVERGED]
    assert all(s.advice and s.advice != Status.CONVERGED.advice for s in Status if not s.ok)
    assert fls.LM_STOPPED == ("converged", "max_iterations", "non_finite")


@pytest.mark.parametrize("edit, expected", [
    ({}, ("converged",)),
    ({"solver": {"stopped": "max_iterations"}}, ("max_iterations",)),
    ({"solver": {"stopped": "non_finite"}, "starts": [{"lm_stopped": "non_finite"}]},
     ("non_finite",)),
    ({"starts": [{"lm_stopped": "converged"}, {"lm_stopped": "non_finite"}]}, ("starts_lost",)),
    ({"starts_disagree": {"message": "..."}}, ("starts_disagree",)),
    ({"parameters": {"albedo": {"at_bound": True}}}, ("at_bound",)),
    ({"mcmc": {"trustworthy": False}}, ("chain_untrusted",)),
    ({"goodness": {"describes_data": False}}, ("misfit",)),
    ({"bootstrap": {"requested": 100, "replicates": 1}}, ("bootstrap_failed",)),
    ({"bootstrap": {"requested": 100, "replicates": 0, "skipped": "2 incidences"}},
     ("converged",)),
    ({"aperture": {"quadrature_error": {"within_tolerance": False}}}, ("aperture_inaccurate",)),
    ({"solver": {"stopped": "max_iterations"}, "goodness": {"describes_data": False}},
     ("max_iterations", "misfit")),
])
def test_channel_statuses_read_the_record(edit, expected):
    from fitlab.fitting.status import channel_statuses

    fit = {"solver": {"stopped": "converged"}, "starts": [{"lm_stopped": "converged"}],
           "starts_disagree": None, "parameters": {"albedo": {"at_bound": False}},
           "mcmc": None, **edit}
    assert channel_statuses(fit) == expected


def test_fit_statuses_and_throw(oren_nayar_data, tmp_path, monkeypatch):
    """A fit stopped by its iteration limit says so in its statuses, raises with the advice
    under throw=True, and reads back the same from its file; a clean fit is ok."""
    import fitlab
    from fitlab.errors import FitlabError
    from fitlab.fitting.status import Status

    m = oren_nayar_data
    good = fitlab.fit(m, "oren_nayar", starts=2, bootstrap=0, throw=True)
    assert good.ok and good.statuses() == (Status.CONVERGED,)
    assert good.raise_for_status() is good
    _no_global_search(monkeypatch, 0.05)
    bad = fitlab.fit(m, "oren_nayar", starts=2, bootstrap=0, lm_maxiter=2)
    assert not bad.ok and Status.MAX_ITERATIONS in bad.statuses()
    assert fitlab.load_fit(bad.save(tmp_path / "f.json").path).statuses() == bad.statuses()
    with pytest.raises(FitlabError, match="max_iterations.*--lm-maxiter"):
        fitlab.fit(m, "oren_nayar", starts=2, bootstrap=0, lm_maxiter=2, throw=True)


def test_starts_on_a_subset_of_many_rows_end_at_the_every_row_optimum(oren_nayar_data,
                                                                      monkeypatch):
    """A fit of more rows than START_SUBSET_ABOVE runs its starts on START_ROWS of them, refines the
    best end on every row (least_squares._refined): the same optimum as the starts run on every
    row, the record says how many rows the starts fitted, and every start's cost is its end's
    cost on every row (computed here in NumPy from the model's values)."""
    from fitlab.fitting.channel import prepare_channel

    m = oren_nayar_data
    p = prepare_channel(m, "oren_nayar", rows=np.ones(m.n, bool))
    space, data, loss = p["space"], p["data"], p["loss"]
    full = fls.fit_least_squares(space, data, loss, n_starts=3, seed=1)
    assert "lm_rows" not in full.global_search
    monkeypatch.setattr(fls, "START_ROWS", 16)
    monkeypatch.setattr(fls, "START_SUBSET_ABOVE", 16)
    sub = fls.fit_least_squares(space, data, loss, n_starts=3, seed=1)
    assert m.n > 16 and sub.global_search["lm_rows"] == 16
    np.testing.assert_allclose(sub.native, full.native, rtol=1e-7)
    np.testing.assert_allclose(sub.stderr, full.stderr, rtol=1e-5)
    assert sub.solver["stopped"] == "converged" and sub.residuals.shape == (m.n,)
    w = np.asarray(data.consts["w"])
    for st in sub.starts:
        end = np.array([st["end"][n] for n in space.names])
        r = (space.predict(end, data.wi, data.wo) - data.value) * w
        assert st["cost"] == pytest.approx(0.5 * float(r @ r), rel=1e-9)
