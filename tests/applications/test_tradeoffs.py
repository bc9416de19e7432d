"""fitlab tradeoffs (fitlab/tradeoffs/): the measured errors are right where the answer is
known — float32 against float64 at a known conditioning, Schlick's Fresnel at normal incidence
(exact), a table read at its texel centres (the storage rounding only) — and the command's
outputs, recommendations and refusals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.export.gltf_material import _measurement
from fitlab.lobe_metrics import directions
from fitlab.report.tradeoffs import pareto_front

ROOT = Path(__file__).resolve().parents[2]


def _data(wi, wo, values=None):
    """A synthetic measurement at the pairs (values only matter as a placeholder)."""
    v = np.ones(len(wi)) if values is None else values
    return _measurement({"Y": v}, wi, wo)


def _variant(res, knob, setting):
    return [v for v in res.variants if v.knob == knob and v.setting == setting][0]


def test_float32_error_is_the_known_rounding_of_a_lambertian():
    """f = ρ/π: in float32 the relative error is that of fl32(fl32(ρ)/fl32(π)) exactly, the
    same at every pair; the measured error must be that number."""
    rho = 0.7
    wi = directions(np.array([0.0, 30.0, 60.0]), 0.0)
    wo = directions(np.array([10.0, 40.0, 70.0]), 90.0)
    res = fitlab.tradeoffs(model="lambertian", params={"albedo": rho}, data=_data(wi, wo),
                           knobs=["precision"])
    f32 = np.float64(np.float32(rho) / np.float32(np.pi))
    want = abs(f32 - rho / np.pi) / (rho / np.pi)
    got = _variant(res, "precision", "float32").errors
    assert want > 0 and got["f_rel_max"] == pytest.approx(want, rel=1e-6)
    assert got["f_rel_rms"] == pytest.approx(want, rel=1e-6)
    assert _variant(res, "precision", "float64").errors["f_rel_max"] == 0.0
    assert 0 < want < np.finfo(np.float32).eps


def test_schlick_is_exact_at_normal_incidence_and_not_elsewhere():
    params = {"alpha": 0.3, "n": 0.2, "k": 3.9}
    normal = directions(np.array([0.0]), 0.0)
    res = fitlab.tradeoffs(model="rough_conductor", params=params, data=_data(normal, normal),
                           knobs=["Fresnel"])
    assert _variant(res, "Fresnel", "fresnel=schlick").errors["f_rel_max"] < 1e-12
    wi = directions(np.array([70.0]), 0.0)
    wo = directions(np.array([70.0]), 180.0)  # the mirror direction: i·h = cos 70°
    res = fitlab.tradeoffs(model="rough_conductor", params=params, data=_data(wi, wo),
                           knobs=["Fresnel"])
    assert _variant(res, "Fresnel", "fresnel=schlick").errors["f_rel_max"] > 1e-3
    assert _variant(res, "Fresnel", "fresnel=exact").current


@pytest.mark.slow  # the knob's mechanism stays in the quick tier (the conductor's test above)
def test_fresnel_knob_measures_the_choices_a_dielectric_offers():
    """rough_dielectric offers exact and schlick (no lazanyi, a metal's approximation): the knob
    measures both, read from the model's option, and Schlick is off at 70° (reflection)."""
    wi = directions(np.array([70.0]), 0.0)
    wo = directions(np.array([70.0]), 180.0)
    res = fitlab.tradeoffs(model="rough_dielectric", params={"alpha": 0.3, "eta": 1.5},
                           data=_data(wi, wo), knobs=["Fresnel"])
    assert {v.setting for v in res.variants} == {"fresnel=exact", "fresnel=schlick"}
    assert _variant(res, "Fresnel", "fresnel=schlick").errors["f_rel_max"] > 1e-3


def test_a_table_at_its_texel_centres_has_only_the_storage_error():
    """At the grid nodes of the 32² table (φd = 90°) the lookup returns the stored values: the
    error is the rounding to float (≤ 2^-24) or half (≤ 2^-11) and no interpolation."""
    from fitlab.lut.axes import grid_coords
    from fitlab.lut.kinds import halfdiff_directions, spec_model

    params = {"alpha": 0.35, "n": 0.2, "k": 3.9}
    spec = spec_model("rough_conductor", {"Y": params}, {}, size=(32, 32),
                      mappings=("u8", "linear", "linear"))
    c = grid_coords(spec.axes)
    c = c[(c[:, 0] > 0.05) & (c[:, 1] > 0.05)]  # wi and wo strictly above the surface
    wi, wo = halfdiff_directions(c[:, 0], c[:, 1], 90.0)
    keep = (wi[:, 2] > 1e-3) & (wo[:, 2] > 1e-3)
    res = fitlab.tradeoffs(model="rough_conductor", params=params,
                           data=_data(wi[keep], wo[keep]), knobs=["tables"], quick=True)
    fl = _variant(res, "tables", "32² float u8").errors
    half = _variant(res, "tables", "32² half u8").errors
    assert fl["f_rel_max"] <= 2.0 ** -24 * 1.01
    assert 0 < half["f_rel_max"] <= 2.0 ** -11 * 1.01
    # between the nodes the same table interpolates: a larger error
    assert _variant(res, "tables", "128² float u8").errors["f_rel_max"] > fl["f_rel_max"]


def test_knobs_that_do_not_apply_say_why():
    res = fitlab.tradeoffs(model="lambertian", params={"albedo": 0.5},
                           knobs=["Fresnel", "G1 (Beckmann)", "masking correlation",
                                  "MCMC length"])
    assert not res.variants
    assert "no option 'fresnel'" in res.skipped["Fresnel"]
    assert "needs a fit" in res.skipped["MCMC length"]
    assert set(res.skipped) == {"Fresnel", "G1 (Beckmann)", "masking correlation",
                                "MCMC length"}
    with pytest.raises(fitlab.errors.FitlabError, match="unknown knob"):
        fitlab.tradeoffs(model="lambertian", params={"albedo": 0.5}, knobs=["nope"])


def test_beckmann_g1_knob_and_pareto_front():
    res = fitlab.tradeoffs(model="rough_conductor",
                           params={"alpha": 0.3, "n": 0.2, "k": 3.9},
                           options={"distribution": "beckmann_rational"},
                           knobs=["G1 (Beckmann)"])
    exact = _variant(res, "G1 (Beckmann)", "distribution=beckmann")
    rational = _variant(res, "G1 (Beckmann)", "distribution=beckmann_rational")
    assert rational.current and not exact.current and exact.errors["f_rel_rms"] == 0.0
    # Walter's rational G1 is within 0.35 % of erf's (eq. 27): f·cos differs by less
    assert 0 < rational.errors["f_rel_max"] < 0.01
    assert pareto_front([(1, 3), (2, 2), (3, 2.5), (0.5, 5), (4, 1)]) == [3, 0, 1, 4]


@pytest.mark.slow
def test_cli_on_the_walter_fit_writes_the_report(tmp_path, capsys):
    """In this process (the console script itself is tests/cli/test_cli.py's)."""
    from fitlab.cli import main

    out = tmp_path / "tr"
    assert main(["tradeoffs", str(ROOT / "fits" / "walter_rough_glass.json"), "--out",
                 str(out), "--quick"]) == 0
    err = capsys.readouterr().err
    assert "offline render:" in err and "fitting:" in err and "[1/" in err
    doc = json.loads((out / "tradeoffs.json").read_text())
    assert doc["format"] == "fitlab-tradeoffs" and doc["material"]["model"] == "rough_dielectric"
    assert doc["directions"].startswith("the 276 measured direction pairs")
    knobs = {v["knob"] for v in doc["variants"]}
    assert {"precision", "tables", "albedo quadrature", "sampled albedo",
            "MCMC length"} <= knobs
    assert set(doc["recommendations"]) == {"offline render", "real-time shader", "fitting"}
    assert not doc["material"]["fit"].startswith("/")
    page = (out / "index.html").read_text()
    assert "Recommendations" in page and "data:image/png;base64," in page
    assert (out / "pareto.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for args, msg in [([str(tmp_path / "missing.json")], "missing.json"),
                      (["--model", "lambertian", "--param", "albedo=2"], "albedo"),
                      (["--model", "lambertian", "--param", "albedo=0.5", "--knob", "x"],
                       "unknown knob")]:
        assert main(["tradeoffs", *args, "--out", str(tmp_path / "bad")]) == 2
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err, err
        assert not (tmp_path / "bad").exists()
