"""`fitlab report`: reports for a BTDF fit with relative units and a chain (Walter), an absolute
BRDF fit with out-of-plane data and a chain, and a fit without a chain all build; the HTML parses
and references only embedded content; every image has alt text; output is byte-for-byte
deterministic; bad inputs fail cleanly; figure functions return Figures without a display."""

from __future__ import annotations

import json
import os
import re
import shutil
import sys
import xml.etree.ElementTree as ET
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "data_formats" / "examples"
WALTER = EXAMPLES / "walter_rough_glass.csv"
RGB = EXAMPLES / "measurement_rgb_sigma.csv"


# --------------------------------------------------------------------------------------------
# Fits made in the tests (small, fast) and their reports
# --------------------------------------------------------------------------------------------


def _write_brdf_csv(path):
    """Synthetic absolute BRDF with sigma: rough conductor, in-plane scans plus an out-of-plane
    grid at two incidences, 4% multiplicative noise."""
    rng = np.random.default_rng(11)
    rows = []
    for ti in (20.0, 50.0):
        for to in np.arange(0.0, 86.0, 5.0):
            for po in (0.0, 180.0):
                rows.append((ti, 0.0, to, po))
        for to in np.arange(10.0, 81.0, 10.0):
            for po in np.arange(30.0, 331.0, 30.0):
                if po != 180.0:
                    rows.append((ti, 0.0, to, po))
    a = np.array(rows)
    from fitlab.io.directions import degrees_to_direction

    wi, wo = degrees_to_direction(a[:, 0], a[:, 1]), degrees_to_direction(a[:, 2], a[:, 3])
    f = np.asarray(fitlab.eval_bsdf("rough_conductor", {"alpha": 0.25, "n": 1.2, "k": 3.0}, wi,
                                    wo))
    v = f * np.exp(0.04 * rng.standard_normal(f.shape))
    sigma = 0.04 * v + 1e-4
    lines = ["# synthetic rough conductor for the report tests", "# quantity: bsdf",
             "# scatter: brdf", "# sample: synthetic rough metal", "theta_i,phi_i,theta_o,phi_o,"
             "value,sigma"]
    lines += [f"{r[0]:g},{r[1]:g},{r[2]:g},{r[3]:g},{x:.6e},{s:.6e}"
              for r, x, s in zip(a, v, sigma)]
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """Three fits and their reports: walter (BTDF, relative, chain), brdf (absolute, sigma,
    out-of-plane, chain), nochain (three channels, no MCMC)."""
    d = tmp_path_factory.mktemp("report")
    out = {}
    fit, chain = d / "walter.json", d / "walter_chain.npz"
    assert main(["fit", str(WALTER), "--model", "rough_dielectric", "--fit-subset",
                 "theta_i == 0", "--mcmc", "--mcmc-steps", "300", "--walter-diagnostics",
                 "--out", str(fit), "--chain", str(chain), "--quiet"]) == 0
    out["walter"] = (fit, chain)
    data = d / "brdf.csv"
    _write_brdf_csv(data)
    fit, chain = d / "brdf.json", d / "brdf_chain.npz"
    assert main(["fit", str(data), "--model", "rough_conductor", "--fix", "k=3", "--mcmc",
                 "--mcmc-steps", "300", "--out", str(fit), "--chain", str(chain),
                 "--quiet"]) == 0
    out["brdf"] = (fit, chain)
    fit = d / "nochain.json"
    assert main(["fit", str(RGB), "--model", "lambertian", "--out", str(fit), "--quiet"]) == 0
    out["nochain"] = (fit, None)
    reports = {}
    for name, (fit, chain) in out.items():
        argv = ["report", str(fit), "--out", str(d / f"rep_{name}"), "--quiet"]
        if chain is not None:
            argv[2:2] = ["--chain", str(chain)]
        assert main(argv) == 0
        reports[name] = d / f"rep_{name}"
    return {"fits": out, "reports": reports, "dir": d}


class _Page(HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags, self.imgs, self.attrs, self.text = [], [], [], []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        a = dict(attrs)
        self.attrs.append((tag, a))
        if tag == "img":
            self.imgs.append(a)

    def handle_data(self, data):
        self.text.append(data)


def _parse(index: Path) -> _Page:
    page = _Page()
    page.feed(index.read_text(encoding="utf-8"))
    page.close()
    return page


def _figure_files(index: Path) -> list:
    m = re.search(r'<meta name="fitlab-report-files" content="([^"]*)">', index.read_text())
    return m.group(1).split()


@pytest.mark.parametrize("name", ["walter", "brdf", "nochain"])
def test_report_builds_self_contained(made, name):
    rep = made["reports"][name]
    index = rep / "index.html"
    page = _parse(index)
    html_text = index.read_text(encoding="utf-8")
    assert page.tags[0] == "html" and "body" in page.tags
    # Only embedded content: no scripts, external styles, frames, or URLs to anywhere.
    assert not {"script", "link", "iframe", "object", "embed"} & set(page.tags)
    outside_data = re.sub(r'src="data:image/png;base64,[A-Za-z0-9+/=]*"', "", html_text)
    assert not re.search(r"https?:|//|file:|url\(|@import", outside_data, flags=re.I)
    for tag, a in page.attrs:
        if "src" in a:
            assert a["src"].startswith("data:image/png;base64,"), (tag, a["src"][:40])
        if "href" in a:
            assert a["href"].startswith("#"), a["href"]
    # Every image: alt text, decodable PNG whose size matches the width/height attributes.
    assert page.imgs
    import base64
    import struct

    for img in page.imgs:
        assert img.get("alt", "").strip()
        png = base64.b64decode(img["src"].split(",", 1)[1])
        assert png[:8] == b"\x89PNG\r\n\x1a\n"
        assert struct.unpack(">II", png[16:24]) == (int(img["width"]), int(img["height"]))
    # The figures beside the page: PNG and SVG, the SVG well-formed; nothing else.
    files = _figure_files(index)
    assert len(files) == 2 * len(page.imgs)
    assert sorted(p.name for p in rep.iterdir()) == sorted(files + ["index.html"])
    for f in files:
        data = (rep / f).read_bytes()
        if f.endswith(".svg"):
            ET.fromstring(data)
            assert b"<dc:date>" not in data
        else:
            assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert any(t.startswith("Parameters") for t in page.text)
    assert all(len(t) < 5000 for t in page.text)  # no image data leaked into the text


def test_report_content_matches_the_fit(made):
    """The numbers in the page are the parameter file's; each report has the sections its fit
    calls for."""
    names = {k: sorted(p.stem for p in v.glob("*.png")) for k, v in made["reports"].items()}
    text = {k: (v / "index.html").read_text(encoding="utf-8") for k, v in made["reports"].items()}
    # Walter (BTDF, relative, chain): scans at the four incidences, lobes with transmission,
    # corner/trace, empirical D and the fit-vs-prediction table; the short chain is flagged.
    assert [n for n in names["walter"] if n.startswith("scan_")] == [
        "scan_Y_theta0_phi0", "scan_Y_theta30_phi0", "scan_Y_theta60_phi0", "scan_Y_theta80_phi0"]
    for fig in ("corner_Y", "trace_Y", "empirical_D_Y", "lobes_Y", "correlation_Y"):
        assert fig in names["walter"]
    assert "hemisphere_Y" not in names["walter"]  # in-plane data: no maps
    w = text["walter"]
    assert "Fit subset against prediction" in w and "scale·f" not in w.split("<h2>")[0]
    assert "This chain is not trustworthy" in w  # 300 steps is too short, and the page says so
    rec = json.loads(made["fits"]["walter"][0].read_text())
    alpha = rec["fits"][0]["parameters"]["alpha"]
    assert f"{alpha['value']:.6g}" in w and f"{alpha['posterior']['median']:.6g}" in w
    assert f"{alpha['posterior']['p2_5']:.6g}" in w
    # BRDF with out-of-plane rows and a chain: hemisphere maps, no transmission lobe.
    assert "hemisphere_Y" in names["brdf"] and "corner_Y" in names["brdf"]
    assert "the model has no transmission lobe" in text["brdf"]
    assert "Fit subset against prediction" not in text["brdf"]
    # No chain: every channel still reported, no posterior figures, and a note saying why.
    assert {n.split("_")[1] for n in names["nochain"] if n.startswith("scan_")} == {"R", "G", "B"}
    assert not any(n.startswith(("corner", "trace")) for n in names["nochain"])
    assert "no chain: the fit ran without MCMC" in text["nochain"]
    assert "No MCMC run for this fit" in text["nochain"]


@pytest.mark.slow
def test_report_is_deterministic(made):
    fit, chain = made["fits"]["walter"]
    # beside the first report: the page names the fit, data and chain relative to its folder
    again = made["dir"] / "rep_walter_again"
    assert main(["report", str(fit), "--chain", str(chain), "--out", str(again), "--quiet"]) == 0
    first = made["reports"]["walter"]
    assert sorted(p.name for p in again.iterdir()) == sorted(p.name for p in first.iterdir())
    for p in first.iterdir():
        assert (again / p.name).read_bytes() == p.read_bytes(), p.name


@pytest.mark.slow
def test_chain_found_through_the_fit_file(made, tmp_path, capsys):
    """`fitlab fit --chain` records the chain's path and hash; the report finds it alone and
    refuses a chain whose hash differs."""
    fit, chain = made["fits"]["walter"]
    rec = json.loads(fit.read_text())
    # stored relative to the fit file's folder (no absolute path of this machine)
    assert rec["chain"]["path"] == os.path.relpath(chain, fit.parent)
    assert not os.path.isabs(rec["data"]["path"]) and len(rec["chain"]["sha256"]) == 64
    out = tmp_path / "r"
    assert main(["report", str(fit), "--out", str(out), "--quiet"]) == 0
    assert (out / "corner_Y.png").exists()
    # A copy of the chain whose bytes differ (same arrays, re-saved) is not the recorded one.
    other = tmp_path / "resaved.npz"
    with np.load(chain) as npz:
        np.savez(other, **{k: npz[k] for k in npz.files})
    assert main(["report", str(fit), "--chain", str(other), "--out", str(tmp_path / "x")]) == 2
    assert "SHA-256 differs" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def _bad_fit_copy(tmp_path, made, edit, which="walter"):
    fit, _ = made["fits"][which]
    rec = json.loads(fit.read_text())
    p = tmp_path / "edited.json"
    # the recorded paths are relative to the fit's folder: keep them pointing at the same files
    for key in ("data", "chain"):
        if (rec.get(key) or {}).get("path"):
            rec[key]["path"] = os.path.relpath(fit.parent / rec[key]["path"], p.parent)
    edit(rec)
    p.write_text(json.dumps(rec))
    return p


@pytest.mark.parametrize("case, fragment", [
    ("missing_data", "which does not exist"),
    ("other_data", "is not the file"),
    ("wrong_schema", "is not a fitlab parameter file"),
    ("wrong_version", "schema_version 7"),
    ("chain_of_other_fit", "do not match the fit's free parameters"),
    ("chain_without_mcmc", "records no MCMC run"),
    ("chain_not_npz", "is not a NumPy .npz archive"),
    ("chain_missing", "no such chain file"),
    ("chain_tampered", "is not this fit's chain"),
])
def test_bad_inputs_fail_cleanly(made, tmp_path, capsys, case, fragment):
    walter_fit, walter_chain = made["fits"]["walter"]
    argv = None
    if case == "missing_data":
        fit = _bad_fit_copy(tmp_path, made, lambda r: r["data"].update(path="nowhere/x.csv"))
        argv = [str(fit), "--chain", str(walter_chain)]
    elif case == "other_data":
        argv = [str(walter_fit), "--data", str(RGB)]
    elif case == "wrong_schema":
        fit = _bad_fit_copy(tmp_path, made, lambda r: r.update(schema="something-else"))
        argv = [str(fit)]
    elif case == "wrong_version":
        fit = _bad_fit_copy(tmp_path, made, lambda r: r.update(schema_version=7))
        argv = [str(fit)]
    elif case == "chain_of_other_fit":
        # Without the recorded hash (older files), the coordinates catch it.
        fit = _bad_fit_copy(tmp_path, made, lambda r: r.pop("chain"), which="brdf")
        argv = [str(fit), "--chain", str(walter_chain)]
    elif case == "chain_without_mcmc":
        argv = [str(made["fits"]["nochain"][0]), "--chain", str(walter_chain)]
    elif case == "chain_not_npz":
        bad = tmp_path / "chain.npz"
        bad.write_text("not a zip file\n")
        argv = [str(_bad_fit_copy(tmp_path, made, lambda r: r.pop("chain"))), "--chain",
                str(bad)]
    elif case == "chain_missing":
        argv = [str(walter_fit), "--chain", str(tmp_path / "absent.npz")]
    elif case == "chain_tampered":
        # Same shapes and names, other samples (and no recorded hash to catch it first).
        fake = tmp_path / "fake.npz"
        with np.load(walter_chain) as npz:
            arrays = {k: npz[k] for k in npz.files}
        arrays["samples_Y"] = arrays["samples_Y"] * 1.01
        np.savez(fake, **arrays)
        argv = [str(_bad_fit_copy(tmp_path, made, lambda r: r.pop("chain"))), "--chain",
                str(fake)]
    out = tmp_path / "out"
    assert main(["report", *argv, "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert fragment in err and err.startswith("fitlab report: error: ")
    assert not out.exists()  # nothing written


def test_fit_with_report_in_one_go(tmp_path, capsys):
    fit, rep = tmp_path / "fit.json", tmp_path / "rep"
    assert main(["fit", str(RGB), "--model", "lambertian", "--out", str(fit), "--report",
                 str(rep)]) == 0
    err = capsys.readouterr().err
    assert "report: figure" in err and f"wrote the report {rep / 'index.html'}" in err
    assert (rep / "index.html").exists() and (rep / "lobes_R.png").exists()
    assert main(["fit", str(RGB), "--model", "lambertian", "--report", str(rep)]) == 2
    assert "--report needs --out" in capsys.readouterr().err


@pytest.mark.slow
def test_rebuild_removes_only_stale_figures(made, tmp_path):
    fit, chain = made["fits"]["walter"]
    out = tmp_path / "r"
    shutil.copytree(made["reports"]["walter"], out)
    (out / "mine.txt").write_text("keep me")
    rec = json.loads(fit.read_text())
    rec.pop("chain")
    bare = tmp_path / "bare.json"
    bare.write_text(json.dumps(rec))
    assert main(["report", str(bare), "--out", str(out), "--quiet"]) == 0
    left = {p.name for p in out.iterdir()}
    assert "corner_Y.png" not in left and "trace_Y.svg" not in left  # no chain now
    assert "mine.txt" in left and "scan_Y_theta30_phi0.png" in left


# --------------------------------------------------------------------------------------------
# Figure functions and helpers
# --------------------------------------------------------------------------------------------


def test_figure_functions_return_figures_without_a_display():
    import matplotlib
    from matplotlib.figure import Figure

    from fitlab.report.lobes import Lobe, lobe_figure
    from fitlab.report.maps import MapRow, hemisphere_figure
    from fitlab.report.posterior import corner_figure, correlation_figure, trace_figure
    from fitlab.report.scans import ScanSide, scan_figure
    from fitlab.report.walter import distribution_curves, empirical_D_figure

    rng = np.random.default_rng(0)
    x = np.linspace(-80, 80, 33)
    y = np.exp(-(x / 20) ** 2) + 0.01
    side = ScanSide("reflection", x, y, 0.05 * y, x < 0, y * 1.02, x, y,
                    np.stack([y * s for s in (0.9, 0.95, 1.0, 1.05, 1.1)]), 0.01)
    r = rng.random(200)
    t = rng.random(200) * 2 * np.pi
    figs = [
        scan_figure([side, side._replace(side="transmission", band_dense=None, sigma=None)],
                    title="test", ylabel="f (1/sr)"),
        hemisphere_figure([MapRow("test", r * np.cos(t), r * np.sin(t), 1 + r, 1.1 + r, 0.0)],
                          unit="f (1/sr)"),
        lobe_figure({"reflection": [Lobe(30.0, x, y)], "transmission": [Lobe(30.0, x, y)]},
                    title="test"),
        corner_figure(rng.normal(size=(500, 3)), ["a", "b", "c"], ["1", "sr", ""],
                      np.zeros(3)),
        correlation_figure(np.eye(2), ["a", "b"], source="test"),
        trace_figure(rng.normal(size=(120, 8, 2)), ["a", "b"], burn=10, tau=[3.0, 4.0],
                     log_prob=rng.normal(size=(120, 8))),
    ]
    th = np.linspace(0, 60, 40)
    from fitlab.report.walter import D_curve

    D = D_curve("ggx", 0.3, th)
    figs.append(empirical_D_figure(th, D, distribution_curves(th, D, "ggx", 0.3)))
    for fig in figs:
        assert isinstance(fig, Figure)
        assert fig.canvas.manager is None  # not attached to any window
        for ax in fig.axes:
            if ax.get_visible() and ax.name == "rectilinear" and ax.get_xlabel():
                assert ax.get_xlabel().strip()
    assert matplotlib.get_backend().lower() == "agg"


def test_pyplot_is_never_imported_and_backend_is_agg(tmp_path):
    """In a fresh interpreter with an interactive backend requested, building figures uses Agg
    and never imports pyplot."""
    import os
    import subprocess

    code = ("import sys, numpy as np\n"
            "from fitlab.report.posterior import correlation_figure\n"
            "from fitlab.report.style import render\n"
            "png, svg = render(correlation_figure(np.eye(2), ['a', 'b'], source='t'))\n"
            "import matplotlib\n"
            "assert matplotlib.get_backend().lower() == 'agg', matplotlib.get_backend()\n"
            "assert 'matplotlib.pyplot' not in sys.modules\n"
            "assert png[:4] == b'\\x89PNG' and b'<svg' in svg\n")
    env = {**os.environ, "MPLBACKEND": "TkAgg", "DISPLAY": ""}
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr


def test_matplotlib_only_in_the_report_package():
    offenders = [str(p.relative_to(ROOT)) for p in (ROOT / "fitlab").rglob("*.py")
                 if "report" not in p.relative_to(ROOT / "fitlab").parts
                 and re.search(r"^\s*(import|from)\s+matplotlib", p.read_text(), flags=re.M)]
    assert offenders == []


def test_best_alpha_recovers_the_distribution_of_its_points():
    from fitlab.report.walter import D_curve, best_alpha

    th = np.linspace(0, 70, 50)
    for name, alpha in (("ggx", 0.394), ("beckmann", 0.2), ("phong", 0.5)):
        a, rms = best_alpha(name, th, D_curve(name, alpha, th))
        assert a == pytest.approx(alpha, rel=3e-3) and rms < 0.02


def test_in_plane_geometry():
    from fitlab.io.directions import degrees_to_direction
    from fitlab.report import geometry as geo

    # The forward side holds the mirror direction; the backward side the retro direction.
    x, wi, wo = geo.dense_scan(30.0, 0.0, geo.REFLECTION)
    k = np.argmin(np.abs(x - 30.0))
    mirror = np.array([-wi[0, 0], -wi[0, 1], wi[0, 2]])
    assert np.allclose(wo[k], mirror, atol=np.radians(0.5))
    x, wi, wo = geo.dense_scan(30.0, 0.0, geo.TRANSMISSION)
    assert np.all(wo[:, 2] < 0) and np.all(wo[x > 1, 0] < 0)  # forward = towards −x
    # Classification of measured rows by the azimuth relative to the plane of incidence.
    theta_o = np.array([40.0, 40.0, 40.0, 1.0, 140.0])
    phi_o = np.array([180.0, 0.0, 90.0, 90.0, 181.0])
    wo = degrees_to_direction(theta_o, phi_o)

    class M:  # the attributes geometry reads
        pass

    m = M()
    m.theta_i, m.phi_i = np.full(5, 30.0), np.zeros(5)
    m.theta_o, m.phi_o = theta_o, phi_o
    m.wi, m.wo = degrees_to_direction(m.theta_i, m.phi_i), wo
    mask, xs = geo.in_plane(m, np.arange(5))
    assert mask.tolist() == [True, True, False, True, True]
    assert xs[0] == 40.0 and xs[1] == -40.0 and xs[4] == 40.0
    assert geo.side_of(m, np.arange(5)).tolist() == ["reflection"] * 4 + ["transmission"]


@pytest.mark.slow
def test_report_of_committed_real_data_fit(tmp_path):
    """The brown vinyl fit (Zemax IS-BSDF, 13 incidences, out-of-plane, MCMC recorded but its
    chain not committed): scans, hemisphere maps and a note in place of the posterior plots."""
    fit = ROOT / "fits" / "brown_vinyl_lambert_ggx_dielectric.json"
    out = tmp_path / "vinyl"
    assert main(["report", str(fit), "--out", str(out), "--quiet"]) == 0
    names = sorted(p.stem for p in out.glob("*.png"))
    assert sum(n.startswith("scan_Y_theta") for n in names) == 13
    assert "hemisphere_Y" in names and "corner_Y" not in names
    text = (out / "index.html").read_text(encoding="utf-8")
    assert "its chain file was not given" in text
    assert "Hemispherical maps" in text and "0.12352" in text  # albedo, best fit


def test_noise_scales_come_from_the_chain(made):
    """The per-sample σ_r is read from the full chain at the rows emcee kept; its median is
    the fit's residual noise scale (a posterior over σ_r centred on the least-squares value)."""
    from fitlab.report.inputs import load_inputs

    fit, chain = made["fits"]["walter"]
    (ch,) = load_inputs(fit, chain_path=chain).channels
    assert ch.noise is not None and ch.noise.shape == (ch.samples.shape[0],)
    s_ls = ch.fit["statistics"]["residual_noise_scale"]
    assert np.median(ch.noise) == pytest.approx(s_ls, rel=0.15)
    # chi2 fits sample no noise scale: no predictive band.
    (ch2,) = load_inputs(made["fits"]["brdf"][0], chain_path=made["fits"]["brdf"][1]).channels
    assert ch2.samples is not None and ch2.noise is None


@pytest.mark.parametrize("loss", ["relative", "log", "cos_l2"])
def test_replicated_data_follow_the_loss_noise_model(loss):
    """Residuals of replicated data, computed with the fit's own residual function, have the
    sampled σ_r as their standard deviation."""
    import jax.numpy as jnp

    from fitlab.fitting.losses import loss_weights, residuals
    from fitlab.report.inputs import replicate_data

    rng = np.random.default_rng(5)
    m = np.array([0.5, 2.0, 8.0])
    cos_o = np.array([0.9, 0.5, 0.2])
    sigma = np.full(20000, 0.03)
    v = replicate_data(loss, np.broadcast_to(m, (20000, 3)).copy(), sigma, cos_o, 0.08, rng)
    for k in range(3):
        consts = loss_weights(loss, v[:, k], None, np.full(20000, cos_o[k]))
        if loss == "relative":  # the fitter's floor is relative to the data it sees
            consts = {"w": 1.0 / np.maximum(np.abs(v[:, k]), 0.08)}
        r = np.asarray(residuals(loss, jnp.full(20000, m[k]), jnp.asarray(v[:, k]),
                                 {q: jnp.asarray(w) for q, w in consts.items()}))
        assert np.std(r) == pytest.approx(0.03, rel=0.05), (loss, k)


@pytest.mark.slow
def test_lookup_tables_of_the_fit_are_previewed(made, tmp_path, capsys):
    """Tables baked from the fit are found beside it (header names the fit) or given with
    --lut; their accuracy figures are shown; a table of another fit is refused."""
    from fitlab.export.exr import read_exr

    src, chain = made["fits"]["walter"]
    d = tmp_path / "fitdir"
    d.mkdir()
    fit = d / "walter.json"
    shutil.copy(src, fit)
    assert main(["lut", "model", "--from-fit", str(fit), "--size", "32", "--phi-d", "slice",
                 "--out", str(d / "walter_model.exr"), "--quiet"]) == 0
    fresnel = tmp_path / "copper.exr"  # from a preset, not from any fit
    assert main(["lut", "fresnel", "--preset", "copper", "--size", "32", "--out", str(fresnel),
                 "--quiet"]) == 0
    out = tmp_path / "rep"
    assert main(["report", str(fit), "--data", str(WALTER), "--chain", str(chain), "--lut",
                 str(fresnel), "--out", str(out), "--quiet"]) == 0
    text = (out / "index.html").read_text(encoding="utf-8")
    assert (out / "lut_walter_model.png").exists() and (out / "lut_copper.png").exists()
    acc = read_exr(d / "walter_model.exr").accuracy
    assert f"{acc['interpolation']['max_rel']:.3g}" in text  # the header's figure, shown
    assert "baked from a model and parameters, not from this fit" in text
    # --no-lut-discovery: only the tables given.
    out2 = tmp_path / "rep2"
    assert main(["report", str(fit), "--data", str(WALTER), "--no-lut-discovery", "--out",
                 str(out2), "--quiet"]) == 0
    assert not list(out2.glob("lut_*"))
    # A table of another fit is an error, and nothing is written.
    other = tmp_path / "other.exr"
    assert main(["lut", "model", "--from-fit", str(made["fits"]["brdf"][0]), "--size", "16",
                 "--phi-d", "slice", "--out", str(other), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["report", str(fit), "--data", str(WALTER), "--lut", str(other), "--out",
                 str(tmp_path / "rep3"), "--quiet"]) == 2
    assert "was baked from the fit" in capsys.readouterr().err
    assert not (tmp_path / "rep3").exists()


def test_accuracy_rows_show_every_auto_candidate():
    """A table whose axes were chosen by measurement (fitlab lut --phi-d auto) lists each
    candidate's figures and marks the one kept."""
    from fitlab.report.luts import accuracy_rows

    acc = {"auto": {"check": "parameterization", "chosen": "8x8x4", "reason": "2-axis misses",
                    "candidates": [{"size": "8x8", "max_rel": 0.3, "rms_rel": 0.07},
                                   {"size": "8x8x4", "max_rel": 0.01, "rms_rel": 0.001}]},
           "storage": {"max_rel": 1e-4, "rms_rel": 1e-5, "dtype": "half"}}
    rows = accuracy_rows(acc)
    assert rows[0] == ["auto: parameterization of the 8x8 candidate", 0.3, 0.07, "2-axis misses"]
    assert rows[1][0].endswith("8x8x4 candidate (chosen)") and rows[1][1:3] == [0.01, 0.001]
    assert rows[2][0] == "storage"


# --------------------------------------------------------------------------------------------
# The first screen, the bands and the titles (issue 34)
# --------------------------------------------------------------------------------------------


def test_first_screen_comes_first_and_provenance_last(made):
    """Verdict, parameters with both intervals, the fit error (the parameter file's figure) and
    the key figure come before the contents; the provenance is the last section."""
    from fitlab.metrics import fit_error_of, fit_error_text

    text = (made["reports"]["walter"] / "index.html").read_text(encoding="utf-8")
    lead = text[text.index("</h1>"):text.index("<nav>")]
    rec = json.loads(made["fits"]["walter"][0].read_text())
    fit = rec["fits"][0]
    alpha = fit["parameters"]["alpha"]
    assert 'id="verdict"' in lead and "Not trusted: the MCMC chain" in lead  # 300 steps
    assert "run a longer chain" in lead  # the status's advice
    assert f"{alpha['value']:.5g}" in lead and "68% credible (MCMC)" in lead
    assert f"{alpha['posterior']['p16']:.5g}" in lead  # the credible interval
    assert f"{alpha['value'] - alpha['stderr']:.5g}" in lead  # the least-squares interval
    assert html_escape(fit_error_text(fit_error_of(fit["statistics"]))) in lead
    assert '<figure id="fit_Y"' in lead
    sections = re.findall(r'<section id="([^"]+)">', text)
    assert sections[-1] == "header" and sections[0] == "warnings"
    assert sections.index("parameters-Y") < sections.index("scans-Y")


def html_escape(s):
    import html

    return html.escape(s, quote=True)


def _fit_entry(**over):
    fit = {"channel": "Y", "solver": {"stopped": "converged"},
           "goodness": {"describes_data": True},
           "parameters": {"alpha": {"value": 0.3, "fixed": False, "bounds": [1e-4, 1.0],
                                    "stderr": 0.01, "at_bound": False,
                                    "posterior": {"p16": 0.2905, "p84": 0.3102}},
                          "eta": {"value": 1.5, "fixed": True, "bounds": [1, 3]}},
           "statistics": {"rms_relative_error_fit": 0.05, "n_fit": 10, "n_total": 20}}
    fit.update(over)
    return fit


def test_verdict_reads_the_statuses():
    from fitlab.fitting.status import Status
    from fitlab.report.summary import PROBLEMS, parameter_table, verdict

    assert set(PROBLEMS) == {s for s in Status if not s.ok}  # every failure has its words
    v = verdict([_fit_entry()])
    assert v.trusted and v.sentence == ("Trustworthy: converged, the model describes the data "
                                        "within their noise, and the least-squares and MCMC "
                                        "intervals agree.")
    bound = _fit_entry()
    bound["parameters"]["alpha"].update(value=1.0, at_bound=True)
    v = verdict([bound])
    assert not v.trusted
    assert v.sentence.startswith("Not trusted: least squares ended at the bound alpha = 1; "
                                 "try: widen the parameter's range")
    wide = _fit_entry()
    wide["parameters"]["alpha"]["posterior"] = {"p16": 0.27, "p84": 0.33}
    assert "MCMC interval of alpha is 3× as wide" in verdict([wide]).sentence
    two = [_fit_entry(channel="R"), _fit_entry(channel="G", goodness={"describes_data": False})]
    v = verdict(two)
    assert v.sentence.startswith("Not trusted: the model does not describe the data within "
                                 "their noise (channel G); try: compare models")
    header, rows = parameter_table([_fit_entry()])
    assert header == ["parameter", "best fit", "68% interval (least squares)",
                      "68% credible (MCMC)", "unit"]
    assert rows[0][:4] == ["alpha", "0.3", "[0.29, 0.31]", "[0.2905, 0.3102]"]
    assert rows[1][:4] == ["eta", "1.5", "fixed", "fixed"]


@pytest.mark.parametrize("loss", ["relative", "log", "cos_l2"])
def test_predictive_bands_are_exact_and_smooth(loss):
    """The posterior predictive quantiles are those of many draws of the noise model, and
    smooth along a scan (no draw noise); the linear panel clips them at 0."""
    from fitlab.report.inputs import BAND_QUANTILES, predictive_quantiles, replicate_data

    rng = np.random.default_rng(3)
    x = np.linspace(-80, 80, 161)
    curve = 0.02 + np.exp(-(x / 20) ** 2)
    model = curve[None, :] * np.exp(0.03 * rng.standard_normal((60, 1)))
    noise = 0.08 * np.exp(0.1 * rng.standard_normal(60))
    cos_o = np.cos(np.radians(x))
    q = predictive_quantiles(loss, model, noise, cos_o, 0.01)
    draws = np.concatenate([replicate_data(loss, model, noise, cos_o, 0.01, rng)
                            for _ in range(200)])  # 12000 per direction
    mc = np.percentile(draws, BAND_QUANTILES, axis=0)
    width = mc[4] - mc[0]  # the draws' own error is about 1% of the 95% band's width
    assert np.all(np.abs(q - mc) <= 0.03 * width + 1e-3)
    # smooth: away from grazing (where log and cos_l2 noise grows as 1/cos θo) the bands bend
    # no more than the curve does (one draw per sample, as before, gave 20 to 60 times more)
    def rough(b):
        return (np.abs(np.diff(b, 2, axis=-1)).max(axis=-1) / np.abs(b).max(axis=-1))

    inner = np.abs(x) <= 60
    assert rough(q[:, inner]).max() < 1.5 * rough(curve)


def test_scan_bands_are_clipped_at_zero():
    from matplotlib.collections import PolyCollection

    from fitlab.report.scans import ScanSide, scan_figure

    x = np.linspace(-80, 80, 33)
    y = np.exp(-(x / 20) ** 2) + 0.01
    band = np.stack([y * s for s in (-0.5, 0.5, 1.0, 1.5, 2.0)])  # reaching below 0
    side = ScanSide("reflection", x, y, None, x < 0, y, x, y, band, 0.0, band)
    lin = scan_figure([side], title="t", ylabel="f (1/sr)").axes[0]
    ys = [ln.get_ydata() for ln in lin.lines] + [
        p.vertices[:, 1] for c in lin.collections if isinstance(c, PolyCollection)
        for p in c.get_paths()]
    lowest = min(np.nanmin(np.asarray(v, float)) for v in ys)
    assert lowest >= 0.0


def test_titles_fit_their_axes():
    """Laid out as render() lays them out, no title runs past its axes or the figure (long ones
    are wrapped)."""
    from fitlab.report.goodness import interval_figure
    from fitlab.report.lobes import Lobe, lobe_figure
    from fitlab.report.posterior import corner_figure
    from fitlab.report.summary import Curve, fit_figure
    from fitlab.report.style import PNG_DPI, render, title_room

    x = np.linspace(-80, 80, 33)
    y = np.exp(-(x / 20) ** 2) + 0.01
    long = ("weidlich_wilkie(lambertian+rough_conductor), channel Visible: best fit, without "
            "the scale of relative data")
    figs = [lobe_figure({"reflection": [Lobe(30.0, x, y)]}, title=long),
            corner_figure(np.random.default_rng(0).normal(size=(100, 3)) * 1e-3 + 123.456,
                          ["alpha_long_name", "beta", "gamma"], ["1", "1", "1"], np.zeros(3)),
            interval_figure([("a", 1.0, [("least squares", 0.9, 1.1)])], long)]
    figs.append(fit_figure([("reflection", [Curve("θi = 0°", x, y, x, y, x < 0)])],
                           ylabel="f (1/sr)", title="channel R (the others below)"))
    for fig in figs:
        render(fig)  # wraps the long titles; keeps the PNG's layout
        fig.set_dpi(PNG_DPI)
        fig.draw_without_rendering()
        renderer = fig._get_renderer()
        for text, room in title_room(fig):
            box = text.get_window_extent(renderer)
            assert box.width <= room + 1, text.get_text()
            assert box.x0 >= -1 and box.x1 <= fig.bbox.width + 1, text.get_text()
