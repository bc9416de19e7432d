"""The sanity gates (fitlab/io/gates.py; data_formats/measurement_csv.md, "Sanity gates"): each
refuses a valid but implausible file with exit status 2 and names the fix, each override lets
it through, `--angles radians` reads a radians file as its degrees twin, `fitlab info` lists
what the gates find, and the bundled examples and the real data pass (issue 34, item 1)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import fitlab
from fitlab.cli import main
from fitlab.errors import FitlabError, InputFileError
from fitlab.io.formats import read_any
from fitlab.io.gates import GATES, findings, notes

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "data_formats" / "examples"
INVALID = EXAMPLES / "invalid"
SHARED = ROOT.parent / "shared" / "data"

#: example -> (gate, a fragment of the fix its refusal names, the overrides that let it through)
CASES = {
    "sanity_radians.csv": ("radians", "--angles radians",
                           [["--angles", "radians"], ["--accept", "radians"]]),
    "sanity_radians_btdf.csv": ("radians", "--angles radians", [["--angles", "radians"]]),
    "sanity_quantity_cos.csv": ("quantity", "--quantity bsdf_cos",
                                [["--quantity", "bsdf_cos"], ["--accept", "quantity"]]),
    "sanity_radiance_factor.csv": ("quantity", "--quantity radiance_factor",
                                   [["--quantity", "radiance_factor"], ["--accept", "quantity"]]),
    "sanity_negative.csv": ("negative", "dark level", [["--accept", "negative"]]),
    "sanity_tis.bsdf": ("tis", "--accept tis", [["--accept", "tis"]]),
}


def test_every_sanity_example_is_documented_and_tested():
    spec = (ROOT / "data_formats" / "measurement_csv.md").read_text()
    files = {p.name for p in INVALID.glob("sanity_*")}
    assert files == set(CASES)
    for name in files:
        assert name in spec, f"{name} missing from measurement_csv.md"
    assert {gate for gate, _, _ in CASES.values()} == set(GATES)


@pytest.mark.parametrize("name", sorted(CASES))
def test_gate_refuses_with_exit_2_naming_the_fix_and_the_override_lets_it_through(
        name, tmp_path, capsys):
    gate, fix, overrides = CASES[name]
    path = INVALID / name
    before = path.read_bytes()
    out = tmp_path / "out.csv"
    assert main(["convert", str(path), str(out)]) == 2
    err = capsys.readouterr().err
    assert f"fitlab convert: error: {path}: sanity gate '{gate}'" in err, err
    assert fix in err and len(err) < 700, err
    assert not out.exists() and path.read_bytes() == before
    for override in overrides:
        assert main(["convert", str(path), str(out), *override]) == 0, override
        err = capsys.readouterr().err
        accepted = [gate] if override[0] == "--accept" else []
        if accepted:
            assert f"accepted by --accept {gate}" in err
        assert fitlab.read(out, accept=accepted).n > 0  # what convert wrote passes the others
        out.unlink()


def test_radians_btdf_gets_the_radians_message_not_one_about_sides(capsys):
    path = INVALID / "sanity_radians_btdf.csv"
    for enforce in (True, False):  # info (enforce=False) too: the sides cannot be read
        with pytest.raises(InputFileError) as e:
            read_any(path, enforce=enforce)
        assert "look like radians" in str(e.value) and "side" not in str(e.value)
    assert main(["info", str(path)]) == 2
    assert "--angles radians" in capsys.readouterr().err
    m = fitlab.read(path, angles="radians")
    assert m.metadata["scatter"] == "btdf" and np.all(m.theta_o > 90)


def _degrees_twin(tmp_path):
    """A degrees CSV (with bins) and the same file in radians."""
    rows = [(30.0, 0.0, to, 180.0, to - 2.5, to + 2.5, 175.0, 185.0, 0.1 + 0.01 * k)
            for k, to in enumerate(np.arange(5.0, 86.0, 10.0))]
    head = ("# quantity: bsdf\n# scatter: brdf\ntheta_i,phi_i,theta_o,phi_o,theta_o_lo,"
            "theta_o_hi,phi_o_lo,phi_o_hi,value\n")
    deg, rad = tmp_path / "deg.csv", tmp_path / "rad.csv"
    deg.write_text(head + "".join(",".join(f"{v:.17g}" for v in r) + "\n" for r in rows))
    rad.write_text(head + "".join(",".join(f"{np.radians(v):.17g}" for v in r[:8])
                                  + f",{r[8]:.17g}\n" for r in rows))
    return deg, rad


def test_angles_radians_gives_the_degrees_files_fit_input(tmp_path, capsys):
    deg, rad = _degrees_twin(tmp_path)
    with pytest.raises(InputFileError, match="sanity gate 'radians'"):
        fitlab.read(rad)
    a, b = fitlab.read(deg), fitlab.read(rad, angles="radians")
    for field in ("theta_i", "phi_i", "theta_o", "phi_o", "wi", "wo", "bin_o_deg"):
        np.testing.assert_allclose(getattr(b, field), getattr(a, field), rtol=1e-13,
                                   atol=1e-13, err_msg=field)
    np.testing.assert_array_equal(b.value, a.value)
    assert b.read_options == {"angles": "radians"} and a.read_options is None
    assert any("read as radians" in n for n in notes(b))
    # a degrees file read as radians is refused, naming the line and the fix
    with pytest.raises(InputFileError, match="drop --angles radians") as e:
        fitlab.read(deg, angles="radians")
    assert e.value.line == 4 and e.value.column == "theta_i"


def test_quantity_override_and_radiance_factor(tmp_path):
    f = tmp_path / "q.csv"
    f.write_text("# quantity: bsdf\ntheta_i,phi_i,theta_o,phi_o,value\n0,0,60,180,0.5\n"
                 "0,0,30,180,0.4\n")
    base = fitlab.read(f)
    np.testing.assert_allclose(fitlab.read(f, quantity="radiance_factor").value,
                               base.value / np.pi, rtol=1e-15)
    np.testing.assert_allclose(fitlab.read(f, quantity="bsdf_cos").value,
                               base.value / np.cos(np.radians([60, 30])), rtol=1e-14)
    m = fitlab.read(f, quantity="relative")
    assert m.is_relative and m.read_options == {"quantity": "relative"}
    f.write_text("# quantity: radiance_factor\ntheta_i,phi_i,theta_o,phi_o,value\n0,0,60,180,0.5\n")
    assert fitlab.read(f).value[0] == pytest.approx(0.5 / np.pi, rel=1e-15)
    assert fitlab.read(f).file_quantity == "radiance_factor"


def test_read_options_are_checked_and_formats_that_fix_them_refuse_them(capsys):
    csv = EXAMPLES / "walter_rough_glass.csv"
    with pytest.raises(FitlabError, match="did you mean 'tis'"):
        fitlab.read(csv, accept=["tiss"])
    with pytest.raises(FitlabError, match="angles 'grad'"):
        fitlab.read(csv, angles="grad")
    with pytest.raises(SystemExit) as e:  # argparse's usage error
        main(["info", str(csv), "--accept", "tiss"])
    assert e.value.code == 2 and "did you mean tis?" in capsys.readouterr().err
    zemax = EXAMPLES / "zemax_brown_vinyl.bsdf"
    assert main(["info", str(zemax), "--quantity", "bsdf_cos"]) == 2
    assert "applies to fitlab's measurement CSV" in capsys.readouterr().err
    with pytest.raises(FitlabError, match="read already"):
        fitlab.fit(fitlab.read(csv), "rough_dielectric", accept=["tis"])
    for command in ("fit", "info", "convert", "compare", "report"):  # one shared definition
        with pytest.raises(SystemExit):
            main([command, "--help"])
        text = capsys.readouterr().out
        assert "--angles" in text and "--accept GATE" in text and "--quantity" in text, command


def test_info_lists_every_gate_tripped_or_accepted(capsys):
    path = str(INVALID / "sanity_negative.csv")
    assert main(["info", path, "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert set(info["sanity_gates"]) == {"radians", "quantity", "negative"}  # no TIS in a CSV
    assert info["sanity_gates"]["negative"].startswith("REFUSES")
    (w,) = info["warnings"]
    assert w.startswith("negative:") and "--accept negative" in w
    assert main(["info", path, "--accept", "negative"]) == 0
    out = capsys.readouterr().out
    assert "accepted by --accept negative" in out and "read_options:" in out
    assert main(["info", str(INVALID / "sanity_tis.bsdf"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["sanity_gates"]["tis"].startswith("REFUSES: AOI 15")
    assert [w.split(":")[0] for w in info["warnings"]] == ["tis"]


def test_negative_noise_rule(tmp_path):
    """Relative data may dip below 0 by detector noise: within 5 sigma, 5 % of the channel's
    largest value and 10 % of its rows; beyond any of the three they are refused."""
    head = "# quantity: relative\ntheta_i,phi_i,theta_o,phi_o,value,sigma\n"
    good = [f"0,0,{t},180,{v},0.01" for t, v in zip(range(5, 86, 5), [1.0] * 16 + [-0.02])]
    f = tmp_path / "n.csv"
    f.write_text(head + "\n".join(good) + "\n")
    assert "within detector noise" in dict(
        (x.gate, x.message) for x in findings(fitlab.read(f)))["negative"]
    f.write_text(head + "\n".join(good[:-1] + ["0,0,85,180,-0.04,0.005"]) + "\n")
    with pytest.raises(InputFileError, match=r"8\.0 sigma below 0"):
        fitlab.read(f)
    f.write_text(head + "\n".join(good[:-3] + [f"0,0,{t},180,-0.01,0.01" for t in (75, 80, 85)])
                 + "\n")
    with pytest.raises(InputFileError, match=r"3 of 17 rows \(18%\) are negative"):
        fitlab.read(f)


def test_rows_line_is_written_and_a_cut_file_is_refused(tmp_path, capsys):
    out = tmp_path / "w.csv"
    assert main(["convert", str(EXAMPLES / "walter_rough_glass.csv"), str(out)]) == 0
    capsys.readouterr()
    lines = out.read_text().splitlines(keepends=True)
    assert "# rows: 276\n" in lines and fitlab.read(out).n == 276
    cut = tmp_path / "cut.csv"
    cut.write_text("".join(lines[:-10]))
    assert main(["info", str(cut)]) == 2
    assert "'# rows: 276' but the file has 266 data rows" in capsys.readouterr().err


def _examples():
    for p in sorted(EXAMPLES.glob("*.csv")) + sorted(EXAMPLES.glob("*.bsdf")):
        if p.name not in ("directions_inplane.csv", "fit_table.csv"):
            yield p


def test_bundled_examples_and_real_data_pass_every_gate():
    for p in _examples():
        # the spectral scan's file states no quantity: the user declares it (spectral_scan_csv.md)
        m = read_any(p, quantity="radiance_factor" if p.name == "spectral_scan.csv" else None)
        assert m.accepted == (), p
        assert not [f for f in findings(m, "csv") if f.tripped], p
    real = ["ansys_optical_automation/test_13_planesymmetric_brdf_zemax.bsdf",
            "rgl_epfl_via_fzy28/aurora_white_rgb.bsdf", "rgl_epfl_via_fzy28/cm_military_green_rgb.bsdf",
            "rgl_epfl_via_fzy28/ilm_solo_m_68_rgb.bsdf", "rgl_epfl_via_fzy28/irid_flake_paint1_rgb.bsdf",
            "lbnl_bsdfxmlparser/2011-SA1.XML", "tekari_pgII/golden_glossy_paper_pgII_theta26.84.txt"]
    present = [SHARED / r for r in real if (SHARED / r).is_file()]
    if not present:
        from conftest import skip_or_fail

        skip_or_fail(f"{SHARED} is not here (the shared data folder sits beside the repository)")
    for p in present:
        read_any(p)  # raises if a gate trips
    scan = SHARED / "ansys_optical_automation/test_brdf_viewer_2D_data.csv"
    if scan.is_file():
        read_any(scan, quantity="radiance_factor")
    pgii = SHARED / real[-1]
    if pgii.is_file():  # raw detector current: 368 negatives, within the noise rule
        found = {f.gate: f for f in findings(read_any(pgii))}
        assert not found["negative"].tripped and "368 negative" in found["negative"].message
        assert not found["tis"].tripped  # #front_integral 0.0263 against 0.02627


def test_a_btdf_whose_tis_the_data_contradict_is_refused():
    """The Lumerical BTDF export (simulated, read with η = 1): -60 % and -99.5 % of its stored
    TIS at 45° and 67.5° of incidence."""
    p = SHARED / "ansys_optical_automation/test_13_brdf_one_wavelength_BTDF_zemax_reference.bsdf"
    if not p.is_file():
        from conftest import skip_or_fail

        skip_or_fail(f"{p} is not here (the shared data folder sits beside the repository)")
    with pytest.raises(InputFileError, match="sanity gate 'tis': AOI 45") as e:
        read_any(p)
    assert "--accept tis" in str(e.value)
    m = read_any(p, accept=["tis"])
    assert m.accepted[0].startswith("tis: AOI 45") and m.read_options == {"accept": ["tis"]}


def test_a_fit_records_how_it_read_the_file_and_the_report_reads_it_so(tmp_path, capsys):
    """A radians twin of the Walter example fitted with --angles radians gives the degrees fit;
    the parameter file records the option, which the report's reader uses."""
    from fitlab.report.inputs import load_data

    src = EXAMPLES / "walter_rough_glass.csv"
    m = fitlab.read(src)
    text = [ln for ln in src.read_text().splitlines() if ln.startswith("#")]
    rows = [f"{np.radians(a):.17g},{np.radians(b):.17g},{np.radians(c):.17g},"
            f"{np.radians(d):.17g},{v * abs(wi):.17g}"
            for a, b, c, d, v, wi in zip(m.theta_i, m.phi_i, m.theta_o, m.phi_o, m.value,
                                         m.wi[:, 2])]
    rad = tmp_path / "walter_rad.csv"
    rad.write_text("\n".join(text + ["theta_i,phi_i,theta_o,phi_o,value"] + rows) + "\n")
    fits = {}
    for name, path, extra in (("deg", src, []), ("rad", rad, ["--angles", "radians"])):
        out = tmp_path / f"{name}.json"
        assert main(["fit", str(path), "--model", "rough_dielectric", "--fit-subset",
                     "theta_i == 0", "--bootstrap", "0", "--starts", "1", "--quiet",
                     "--out", str(out), *extra]) == 0
        fits[name] = json.loads(out.read_text())
    capsys.readouterr()
    alpha = [fits[k]["fits"][0]["parameters"]["alpha"]["value"] for k in ("deg", "rad")]
    assert alpha[1] == pytest.approx(alpha[0], rel=1e-6)
    assert fits["rad"]["data"]["read_options"] == {"angles": "radians"}
    assert "read_options" not in fits["deg"]["data"]
    assert any("read as radians" in n for n in fits["rad"]["notes"])
    again, _ = load_data(fits["rad"], tmp_path / "rad.json")
    np.testing.assert_allclose(again.theta_o, m.theta_o, rtol=1e-13)
