"""Batched fits (``fitlab.fit_many``, ``fitlab fit FILE FILE ...``): the same optimum as a single
fit, grouping by structure, chunking that does not change results, the parameter files and the
table, the CLI and its refusals."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.errors import FitlabError

ROOT = Path(__file__).resolve().parents[2]
WALTER = ROOT / "data_formats" / "examples" / "walter_rough_glass.csv"
RGB = ROOT / "data_formats" / "examples" / "measurement_rgb_sigma.csv"


@pytest.fixture(scope="module")
def synthetic():
    """Five datasets of the Walter example's structure (normal incidence, relative data) with
    known α and scale, 5 % noise."""
    m = fitlab.read(WALTER)
    base = m.select(m.theta_i == 0)
    rng = np.random.default_rng(4)
    truth = np.stack([rng.uniform(0.15, 0.5, 5), rng.uniform(0.7, 1.5, 5)], axis=1)
    out = []
    for k, (a, s) in enumerate(truth):
        f = np.asarray(fitlab.eval_bsdf("rough_dielectric", {"alpha": a, "eta": base.eta()},
                                        base.wi, base.wo))
        v = s * f * (1 + 0.05 * rng.standard_normal(f.shape))
        out.append(base._replace(value=np.maximum(v, 0.0), path=f"synthetic_{k}.csv"))
    return out, truth


def test_batched_fit_equals_the_single_fit():
    m = fitlab.read(WALTER)
    many = fitlab.fit_many([m], "rough_dielectric", subset="theta_i == 0")
    single = fitlab.fit(m, "rough_dielectric", subset="theta_i == 0", bootstrap=0)
    got = many.parameters(0)
    for name in ("alpha", "scale"):
        assert got[name] == pytest.approx(single.parameters["Y"][name], rel=1e-7)
    f = many.fits[0]
    for name, se in zip(f.names, f.stderr):
        assert se == pytest.approx(single.stderr["Y"][name], rel=1e-5)
    assert f.lm_stopped == "converged" and many.groups == 1


def test_recovers_known_values_and_chunks_do_not_change_results(synthetic):
    ms, truth = synthetic
    one = fitlab.fit_many(ms, "rough_dielectric")
    two = fitlab.fit_many(ms, "rough_dielectric", chunk=2)  # chunks of 2, the last padded
    a1 = np.array([f.native for f in one.fits])
    a2 = np.array([f.native for f in two.fits])
    np.testing.assert_allclose(a1, a2, rtol=1e-9)
    assert np.all(np.abs(a1 - truth) <= 0.05 * truth), (a1, truth)  # 5 % noise, 69 rows
    assert [f.dataset for f in one.fits] == list(range(5))
    # statuses by the single fit's rule (fitlab.fitting.status): these converge inside the box
    assert one.ok and all(one.statuses(k) == ("converged",) for k in range(5))
    assert one.raise_for_status() is one


def test_a_fit_stopped_by_its_iteration_limit_is_not_ok(synthetic):
    from fitlab.errors import FitlabError
    from fitlab.fitting.status import Status

    ms, _ = synthetic
    short = fitlab.fit_many(ms[:2], "rough_dielectric", lm_maxiter=1)
    assert not short.ok and Status.MAX_ITERATIONS in short.statuses(0)
    with pytest.raises(FitlabError, match="dataset 0 channel Y: max_iterations"):
        fitlab.fit_many(ms[:2], "rough_dielectric", lm_maxiter=1, throw=True)


def test_batched_solver_refills_its_lanes_and_runs_each_start_as_the_single_fit():
    """fitlab.fitting.lm ``lm_queue`` on nonlinear least-squares problems (y = a exp(-b x),
    three datasets): seven starts on two lanes, each start's run is the single fit's
    (``lm_until``, run alone) and ends at scipy.optimize.least_squares's optimum; a run that
    spends ``maxiter`` steps reports its rule unmet; the slots past ``n`` are not run."""
    import jax
    import jax.numpy as jnp
    from scipy.optimize import least_squares

    from fitlab.fitting.lm import lm_queue, lm_until

    x = np.linspace(0.0, 4.0, 40)
    rng = np.random.default_rng(0)
    truth = [(2.0, 1.3), (0.5, 0.4), (3.0, 2.5)]
    Y = np.stack([a * np.exp(-b * x) + 0.01 * rng.standard_normal(40) for a, b in truth])

    def residual(z, y):
        return z[0] * jnp.exp(-z[1] * jnp.asarray(x)) - y

    tol = dict(xtol=1e-10, gtol=1e-10, tau=1e-6)
    Z0 = np.array([[1.0, 0.5], [5.0, 5.0], [1.0, 0.5], [0.1, 0.1], [2.0, 3.0], [1.0, 1.0],
                   [4.0, 0.2], [9.0, 9.0]])
    which = np.array([0, 0, 1, 1, 2, 2, 0, 0])
    run = jax.jit(lambda Z0, n, maxiter: lm_queue(residual, Z0, jnp.asarray(Y), which, n,
                                                  lanes=2, maxiter=maxiter, **tol),
                  static_argnums=2)
    out = {k: np.asarray(v) for k, v in run(Z0, 7, 200).items()}
    alone = jax.jit(jax.vmap(lambda z0, y: lm_until(residual, z0, y, maxiter=200, **tol)))(
        Z0[:7], Y[which[:7]])
    np.testing.assert_allclose(out["z"][:7], np.asarray(alone["z"]), rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(out["iters"][:7], np.asarray(alone["iters"]))
    assert np.all(out["rule_met"][:7]) and np.all(out["finite"][:7])
    for i in range(7):
        want = least_squares(lambda z: z[0] * np.exp(-z[1] * x) - Y[which[i]], Z0[i],
                             xtol=1e-14, ftol=1e-14, gtol=1e-14).x
        np.testing.assert_allclose(out["z"][i], want, rtol=1e-6)
    assert not out["finite"][7] and out["iters"][7] == 0  # past n: not run
    short = {k: np.asarray(v) for k, v in run(Z0, 7, 2).items()}
    assert not np.any(short["rule_met"][:7]) and np.all(short["iters"][:7] == 2)


def test_more_lanes_or_fewer_give_the_same_fits(synthetic, monkeypatch):
    """The batched fits' lanes (fitlab.fitting.batch.LANES) change how the runs are scheduled,
    not where they end: two lanes for five datasets give the fits of the default."""
    from fitlab.fitting import batch

    ms, _ = synthetic
    ref = fitlab.fit_many(ms, "rough_dielectric")
    monkeypatch.setattr(batch, "LANES", 2)
    batch._batched.cache_clear()
    try:
        many = fitlab.fit_many(ms, "rough_dielectric")
    finally:
        monkeypatch.undo()
        batch._batched.cache_clear()
    for a, b in zip(ref.fits, many.fits):
        np.testing.assert_allclose(b.native, a.native, rtol=1e-9)
        assert b.lm_stopped == "converged" and b.lm_iterations == a.lm_iterations


def test_more_starts_only_where_the_first_is_suspect(synthetic, monkeypatch):
    """fit_chunk runs LM from the scan's best point; only where that end is suspect
    (batch._suspect) from the model's defaults and the scan's next best points too. Here none
    is (1 start each); made suspect, every dataset runs 1 + 1 + 4 starts and reaches the same
    optimum."""
    from fitlab.fitting import batch

    ms, _ = synthetic
    ref = fitlab.fit_many(ms[:3], "rough_dielectric")
    assert [f.lm_starts for f in ref.fits] == [1, 1, 1]
    assert next(iter(ref.records()))[1]["fits"][0]["global_search"]["lm_starts"] == 1
    monkeypatch.setattr(batch, "_suspect", lambda run, *a: np.ones(len(run["cost"]), bool))
    more = fitlab.fit_many(ms[:3], "rough_dielectric", starts=4)
    assert [f.lm_starts for f in more.fits] == [6, 6, 6]
    for a, b in zip(ref.fits, more.fits):
        np.testing.assert_allclose(b.native, a.native, rtol=1e-7)


def test_a_first_end_is_suspect_when_it_is_not_finite_at_a_bound_or_a_misfit():
    """batch._suspect: chi2 judges each end by its reduced chi-square, another loss by the
    chunk's median reduced cost; an end at a bound or not finite is suspect either way."""
    from fitlab.fitting.batch import SUSPECT_COST_RATIO, SUSPECT_REDUCED_CHI2, _suspect

    n_rows, d = np.full(5, 12), 2  # 10 degrees of freedom: reduced cost = cost / 5
    u = np.full((5, d), 0.5)
    u[3, 1] = 0.0  # at a bound
    cost = np.array([5.0, 5.0, 5.0, 5.0, 5.0])
    finite = np.array([True, True, True, True, False])
    run = {"cost": cost, "end_finite": finite, "u": u, "rule_unmet": np.zeros(5, bool)}
    assert list(_suspect(run, n_rows, d, "relative")) == [False, False, False, True, True]
    worse = dict(run, cost=cost * np.array([1, 1, SUSPECT_COST_RATIO * 1.01, 1, 1]))
    assert list(_suspect(worse, n_rows, d, "relative")) == [False, False, True, True, True]
    assert list(_suspect(run, n_rows, d, "chi2")) == [False, False, False, True, True]
    chi = dict(run, cost=np.full(5, 5.0 * SUSPECT_REDUCED_CHI2 * 1.01))
    assert list(_suspect(chi, n_rows, d, "chi2")) == [True] * 5
    assert list(_suspect(chi, n_rows, d, "relative")) == [False, False, False, True, True]
    short = dict(run, rule_unmet=np.array([False, True, False, False, False]))  # out of steps
    assert list(_suspect(short, n_rows, d, "relative")) == [False, True, False, True, True]


def test_structures_are_grouped(synthetic):
    """The RGB file (chi2 loss: it has sigma; 4 rows) and the synthetic sets (relative loss,
    69 rows) are two structures; every channel is a dataset."""
    ms, _ = synthetic
    r = fitlab.fit_many([ms[0], fitlab.read(RGB), ms[1]], "rough_conductor")
    assert r.groups == 2
    assert [(f.dataset, f.channel) for f in r.fits] == [(0, "Y"), (1, "R"), (1, "G"), (1, "B"),
                                                        (2, "Y")]
    assert r.loss == {0: "relative", 1: "chi2", 2: "relative"}


def test_records_are_parameter_files_and_table_has_every_fit(tmp_path, synthetic):
    from fitlab.export.paramfile import write_fit

    ms, truth = synthetic
    r = fitlab.fit_many(ms[:2], "rough_dielectric")
    for i, record in r.records():
        path = tmp_path / f"{i}.json"
        write_fit(path, record)
        loaded = fitlab.load_fit(path)
        assert loaded.parameters["Y"]["alpha"] == pytest.approx(r.parameters(i)["alpha"])
        assert loaded.stderr["Y"]["alpha"] > 0
        assert "fit_many" in " ".join(loaded.record["notes"])
        f = loaded.predict(ms[i].wi, ms[i].wo)
        assert np.all(np.isfinite(f))
    rows = list(csv.DictReader(io.StringIO("".join(r.table().splitlines(True)[1:]))))
    assert [row["dataset"] for row in rows] == ["0", "1"]
    assert float(rows[1]["alpha"]) == r.parameters(1)["alpha"]
    assert float(rows[1]["alpha_stderr"]) == pytest.approx(r.fits[1].stderr[0])


def test_cli_several_files(tmp_path, capsys):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_bytes(WALTER.read_bytes())
    b.write_bytes(WALTER.read_bytes())
    code = main(["fit", str(a), str(b), "--model", "rough_dielectric", "--fit-subset",
                 "theta_i == 0", "--out-dir", str(tmp_path / "fits"), "--table",
                 str(tmp_path / "t.csv")])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "fitted 2 datasets of 2 files" in err and "fits/s" in err
    for name in ("a", "b"):
        r = fitlab.load_fit(tmp_path / "fits" / f"{name}.json")
        assert r.parameters["Y"]["alpha"] == pytest.approx(0.39717, abs=1e-4)
        assert r.record["data"]["path"] == f"../{name}.csv"  # relative, no machine path
    text = (tmp_path / "t.csv").read_text()
    assert text.splitlines()[1].startswith("dataset,source,channel,rows_fitted")
    assert text.splitlines()[2].startswith("0,a.csv,Y,69,")  # relative to the table
    assert str(tmp_path) not in text


@pytest.mark.parametrize("extra,needle", [
    (["--mcmc", "--out-dir", "D"], "--sampler nuts"),
    (["--chain", "x.json", "--out-dir", "D"], "not with --chain"),
    (["--out", "x.json", "--table", "t.csv"], "not with --out"),
    ([], "give --out-dir"),
    (["--out-dir", "D", "--chunk", "0"], "--chunk must be an integer of at least 1"),
    (["--share", "alpha", "--out-dir", "D"], "not with --share"),
    (["--bootstrap", "20", "--table", "t.csv"], "not with --bootstrap"),
])
def test_cli_refusals(tmp_path, capsys, extra, needle):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_bytes(WALTER.read_bytes())
    b.write_bytes(WALTER.read_bytes())
    extra = [str(tmp_path / e) if e in ("D", "x.json", "t.csv") else e for e in extra]
    code = main(["fit", str(a), str(b), "--model", "rough_dielectric", *extra])
    err = capsys.readouterr().err
    assert code == 2 and needle in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "b.csv"]


def test_cli_bad_file_writes_nothing(tmp_path, capsys):
    a, bad = tmp_path / "a.csv", tmp_path / "bad.csv"
    a.write_bytes(WALTER.read_bytes())
    bad.write_text("# quantity: bsdf\ntheta_i,phi_i,theta_o,phi_o,value\n0,0,0,0,oops\n")
    code = main(["fit", str(a), str(bad), "--model", "rough_dielectric", "--out-dir",
                 str(tmp_path / "fits"), "--table", str(tmp_path / "t.csv")])
    err = capsys.readouterr().err
    assert code == 2 and "bad.csv" in err
    assert not (tmp_path / "fits").exists() and not (tmp_path / "t.csv").exists()


@pytest.mark.slow
def test_batched_posteriors_by_nuts(synthetic):
    """fit_many(mcmc=True): NUTS vmapped over the datasets; each posterior centred on its
    least-squares optimum (median within 2 standard errors), trusted, in the table."""
    pytest.importorskip("blackjax")
    ms, truth = synthetic
    r = fitlab.fit_many(ms[:3], "rough_dielectric", mcmc=True, mcmc_steps=300, walkers=4)
    for f in r.fits:
        med = np.median(f.mcmc.samples_native, axis=0)
        assert np.all(np.abs(med - f.native) < 2 * f.stderr), (med, f.native, f.stderr)
        assert f.mcmc.sampler == "nuts" and f.mcmc.samples_native.shape == (1200, 2)
        np.testing.assert_allclose(f.mcmc.samples_native.std(0), f.stderr, rtol=0.25)
    head = r.table().splitlines()[1].split(",")
    assert "alpha_p50" in head and "posterior_trusted" in head
    rec = dict(r.records())[0]
    assert rec["fits"][0]["mcmc"]["sampler"] == "nuts"


@pytest.mark.slow
def test_dataset_column_one_fit_per_dataset(tmp_path, capsys):
    """A file with a dataset column: fit_many and `fitlab fit FILE --out-dir` fit each dataset
    on its own (α of the three synthetic samples back within 3 standard errors), name the
    parameter files STEM.LABEL.json and the table's sources FILE#LABEL; a single fit of the
    file is refused with that advice; a report of one dataset's fit takes its rows."""
    data = ROOT / "data_formats" / "examples" / "measurement_datasets.csv"
    res = fitlab.fit_many(data, "rough_dielectric")
    assert [m.metadata["dataset"] for m in res.measurements] == ["frosted_a", "frosted_b",
                                                                 "frosted_c"]
    for k, truth in enumerate((0.12, 0.25, 0.4)):
        f = [x for x in res.fits if x.dataset == k][0]
        a, e = float(f.native[0]), float(f.stderr[0])
        assert abs(a - truth) < 3 * e + 1e-3, (k, a, e)
    with pytest.raises(FitlabError, match="holds 3 datasets"):
        fitlab.fit(data, "rough_dielectric")
    single = fitlab.fit(fitlab.read(data).dataset_named("frosted_b"), "rough_dielectric")
    assert single.parameters["Y"]["alpha"] == pytest.approx(res.parameters(1)["alpha"], rel=1e-6)
    out = tmp_path / "fits"
    assert main(["fit", str(data), "--model", "rough_dielectric", "--out-dir", str(out),
                 "--table", str(out / "t.csv"), "--quiet"]) == 0
    assert sorted(p.name for p in out.glob("*.json")) == [
        f"measurement_datasets.{x}.json" for x in ("frosted_a", "frosted_b", "frosted_c")]
    rows = (out / "t.csv").read_text().splitlines()[2:]
    assert [r.split(",")[1].rsplit("#", 1)[1] for r in rows] == ["frosted_a", "frosted_b",
                                                                "frosted_c"]
    rec = fitlab.load_fit(out / "measurement_datasets.frosted_c.json")
    assert rec.record["data"]["metadata"]["dataset"] == "frosted_c"
    assert rec.record["data"]["rows"] == fitlab.read(data).dataset_named("frosted_c").n
    capsys.readouterr()
    assert main(["fit", str(data), "--model", "rough_dielectric"]) == 2
    err = capsys.readouterr().err
    assert "holds 3 datasets" in err and "--out-dir" in err
    from fitlab.report.inputs import load_data

    m, _ = load_data(rec.record, out / "measurement_datasets.frosted_c.json")
    assert m.metadata["dataset"] == "frosted_c" and m.n == rec.record["data"]["rows"]


def test_relative_datasets_on_one_geometry_share_the_scan(synthetic, monkeypatch):
    """Relative data (a free scale with bounds of each dataset's own) on the same directions:
    the scan's predictions once per point, times each dataset's scale
    (batch.shared_scan_costs), give the per-dataset scan's costs and the same fits."""
    from fitlab.fitting import batch, many

    ms, _ = synthetic
    seen = []
    real = batch.fit_chunk
    monkeypatch.setattr(many, "fit_chunk", lambda ps, **kw: seen.append((ps, kw)) or real(
        ps, **kw))
    fitlab.fit_many(ms, "rough_dielectric")
    (problems, kw), = seen
    p0 = problems[0]
    stacked = batch._stack(problems, batch.padded_size(p0.n_rows))
    assert len({float(x) for x in stacked["hi"][:, -1]}) == len(ms)  # scale bounds differ
    assert batch.shares_scan(p0.space.static, stacked)
    k = batch._batched(p0.space.static, p0.loss, batch.LM_MAXITER)
    U = batch.scan_points(kw["scan"], p0.space.ndim, kw["seed"])
    np.testing.assert_allclose(np.asarray(k["shared_scan"](U, stacked)),
                               np.asarray(k["batch_scan"](U, stacked)), rtol=1e-12, atol=0)
    once = real(problems, **kw)
    monkeypatch.setattr(batch, "shares_scan", lambda static, stacked: False)
    np.testing.assert_array_equal(real(problems, **kw).native, once.native)


@pytest.mark.parametrize("which", ["relative", "chi2"])
def test_datasets_of_one_geometry_get_the_single_fits_problems(synthetic, which):
    """Datasets measured on one geometry take the first one's problems with values of their
    own (fitlab.fitting.channel ``channel_problems_like``, all at once): the same spaces, data
    and starts, number for number, as ``channel_problem`` makes for each dataset alone; the
    directions are shared, and a copy of the directions (equal, not the same array) is
    recognized too."""
    from fitlab.fitting import many
    from fitlab.fitting.channel import resolve_fit
    from fitlab.fitting.request import as_request

    if which == "relative":
        ms, _ = synthetic
        model = "rough_dielectric"
    else:  # nine channels, sigma, the chi2 loss, each dataset its own values and sigma
        m = fitlab.read(ROOT / "data_formats" / "examples" / "measurement_spectral_visible.csv")
        rng = np.random.default_rng(7)
        ms = [m._replace(value=m.value * rng.uniform(0.8, 1.2, m.n),
                         sigma=m.sigma * rng.uniform(0.8, 1.2, m.n), path=f"rgb_{k}.csv")
              for k in range(4)]
        model = "lambertian+rough_conductor"
    ms = list(ms)
    ms[-1] = ms[-1]._replace(wi=ms[-1].wi.copy(), wo=ms[-1].wo.copy())
    request = as_request(model, dict(many.MANY_DEFAULTS))
    got = many._problems(ms, request)[0]
    want = [p for i, m in enumerate(ms)
            for p in many._own_problems(i, m, np.ones(m.n, bool), resolve_fit(m, request), None)]
    assert len(got) == len(want) == len(ms) * len(ms[0].channel_names)
    for p, q in zip(got, want):
        assert p.key == q.key and p.loss == q.loss and p.n_rows == q.n_rows
        assert p.space == q.space  # bounds (a relative fit's scale: each dataset's own) exact
        np.testing.assert_array_equal(p.start_native, q.start_native)
        for field in ("wi", "wo", "value"):
            np.testing.assert_array_equal(getattr(p.data, field), getattr(q.data, field))
        assert p.data.consts.keys() == q.data.consts.keys()
        for k in p.data.consts:
            np.testing.assert_array_equal(p.data.consts[k], q.data.consts[k])
    # the datasets but the first share the first one's direction arrays (stacked at once)
    per_channel = len(ms[0].channel_names)
    assert all(p.data.wi is got[c].data.wi for c in range(per_channel)
               for p in got[c::per_channel])


def test_the_garbage_collector_is_paused_and_restored():
    """batch.paused_gc: the cyclic collector off inside, back to its state on leaving, also when
    the body raises; left off when it was off."""
    import gc

    from fitlab.fitting.batch import paused_gc

    assert gc.isenabled()
    with pytest.raises(RuntimeError):
        with paused_gc():
            assert not gc.isenabled()
            raise RuntimeError("inside")
    assert gc.isenabled()
    gc.disable()
    try:
        with paused_gc():
            assert not gc.isenabled()
        assert not gc.isenabled()
    finally:
        gc.enable()
