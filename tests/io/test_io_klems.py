"""LBNL WINDOW / Radiance BSDF XML (Klems bases): the real shade-fabric file shipped in
data_formats/examples/lbnl_window_xml/, synthetic files written here (Lambertian, Rows layout,
bounds worked back from 90°), the fitlab geometry (front = +z, diagonal = mirror / straight
through), energy checks, broken files, and the CLI (info, convert, fit)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fitlab.cli import main
from fitlab.errors import FitlabError, InputFileError
from fitlab.io import klems
from fitlab.io.formats import detect_format, read_any
from fitlab.io.measurement import read_measurement

REAL = Path(__file__).resolve().parents[2] / "data_formats" / "examples" / "lbnl_window_xml" / \
    "2011-SA1.XML"
QUARTER = ((0, 9, 27, 46, 66, 90), (1, 8, 12, 12, 8))  # Radiance's LBNL/Klems Quarter


def _basis_xml(name, bounds, nphis, with_bounds=True):
    blocks = []
    for r, n in enumerate(nphis):
        lo, hi = bounds[r], bounds[r + 1]
        centre = 0 if lo == 0 else (lo + hi) / 2
        b = f"<Theta>{centre:g}</Theta><nPhis>{n}</nPhis>"
        if with_bounds:
            b += f"<ThetaBounds><LowerTheta>{lo:g}</LowerTheta><UpperTheta>{hi:g}</UpperTheta></ThetaBounds>"
        blocks.append(f"<AngleBasisBlock>{b}</AngleBasisBlock>")
    return f"<AngleBasis><AngleBasisName>{name}</AngleBasisName>\n" + "\n".join(blocks) + \
        "\n</AngleBasis>"


def _matrix_text(mat):
    return "\n" + "\n".join(", ".join(f"{v:.9g}" for v in row) + "," for row in mat) + "\n"


def klems_xml(blocks, structure="Columns", basis="LBNL/Klems Quarter", with_bounds=True,
              define_basis=True):
    """A WindowElement document; ``blocks`` maps (band, direction) to a matrix (text rows)."""
    defin = _basis_xml(basis, *QUARTER, with_bounds=with_bounds) if define_basis else ""
    parts = ['<?xml version="1.0" encoding="UTF-8"?>',
             '<WindowElement xmlns="http://windows.lbl.gov">',
             "<WindowElementType>System</WindowElementType>", "<Optical><Layer>",
             "<Material><Name>Synthetic</Name><DeviceType>Other</DeviceType></Material>",
             f"<DataDefinition><IncidentDataStructure>{structure}</IncidentDataStructure>",
             defin, "</DataDefinition>"]
    for (band, direction), mat in blocks.items():
        parts += ["<WavelengthData><LayerNumber>System</LayerNumber>",
                  f'<Wavelength unit="Integral">{band}</Wavelength>', "<WavelengthDataBlock>",
                  f"<WavelengthDataDirection>{direction}</WavelengthDataDirection>",
                  f"<ColumnAngleBasis>{basis}</ColumnAngleBasis>",
                  f"<RowAngleBasis>{basis}</RowAngleBasis>",
                  "<ScatteringDataType>BTDF</ScatteringDataType>",
                  f"<ScatteringData>{_matrix_text(mat)}</ScatteringData>",
                  "</WavelengthDataBlock></WavelengthData>"]
    parts += ["</Layer></Optical></WindowElement>"]
    return "\n".join(parts) + "\n"


N_QUARTER = 41


def _lambert_blocks(rho=0.6, tau=0.2):
    one = np.ones((N_QUARTER, N_QUARTER))
    return {("Visible", "Reflection Front"): rho / np.pi * one,
            ("Visible", "Transmission Front"): tau / np.pi * one,
            ("Visible", "Reflection Back"): 0.5 * rho / np.pi * one,
            ("Visible", "Transmission Back"): tau / np.pi * one}


@pytest.fixture
def lambert_xml(tmp_path):
    path = tmp_path / "lambert.xml"
    path.write_text(klems_xml(_lambert_blocks()))
    return path


# --------------------------------------------------------------------------------------------
# The real file
# --------------------------------------------------------------------------------------------


def test_real_file_structure():
    kf = klems.read_klems_file(REAL)
    assert kf.structure == "Columns" and kf.material["Manufacturer"] == "Nysan"
    (basis,) = kf.bases.values()
    assert basis.name == "LBNL/Klems Full" and basis.n == 145
    assert basis.ring_theta.tolist() == [0, 10, 20, 30, 40, 50, 60, 70, 82.5]
    assert basis.ring_nphis.tolist() == [1, 8, 16, 20, 24, 24, 24, 16, 12]
    np.testing.assert_allclose(basis.projected_solid_angle().sum(), np.pi, rtol=1e-12)
    np.testing.assert_allclose(basis.solid_angle().sum(), 2 * np.pi, rtol=1e-12)
    assert [(b.channel, b.direction) for b in kf.blocks] == [
        (band, d) for band in ("Visible", "Solar") for d in klems.DIRECTIONS]
    # every block says "BTDF", reflection blocks included: the label is not used
    assert {b.scattering_data_type for b in kf.blocks} == {"BTDF"}
    tf = kf.blocks[0]
    assert tf.matrix.shape == (145, 145) and tf.line == 107
    assert tf.matrix[0, 0] == 2.063833 and tf.matrix[0, 1] == 0.014938 and tf.matrix[1, 0] == 0.014954
    assert tf.value_lines[0, 0] == 108 and tf.value_lines[144, 0] == 252


def test_real_file_energy_figures():
    checks = klems.energy_checks(klems.read_klems_file(REAL))
    vis = checks["Visible"]
    # normal-incidence diagonal: the 5% openness seen as a direct beam T/(Λ) over the diffuse level
    assert vis["Transmission Front"]["diagonal_normal_incidence"] == 2.063833
    assert vis["Transmission Front"]["direct_part_normal_incidence"] == pytest.approx(0.0489, abs=2e-4)
    assert vis["Transmission Front"]["hemispherical"]["normal_incidence"] == pytest.approx(0.0959, abs=1e-4)
    # reflection at normal incidence is uniform (Lambertian): R = π · 0.153571
    assert vis["Reflection Front"]["hemispherical"]["normal_incidence"] == pytest.approx(
        np.pi * 0.153571, abs=1e-6)
    assert vis["Reflection Front"]["direct_part_normal_incidence"] == 0.0
    for band in ("Visible", "Solar"):
        for key, rec in checks[band].items():
            assert rec["at_most_1"], (band, key)
        for side in ("Front", "Back"):
            assert checks[band][f"T+R {side}"]["max"] < 0.75
    assert checks["Solar"]["T+R Front"]["normal_incidence"] == pytest.approx(0.5833, abs=1e-4)


def test_real_file_geometry():
    m = klems.read_klems(REAL, channels="Visible")
    assert m.n == 4 * 145 * 145 and m.channel_names == ("Visible",) and m.quantity == "bsdf"
    blocks = m.metadata["blocks"].split(", ")
    assert blocks == list(klems.DIRECTIONS)
    per = 145 * 145
    tf, tb, rf, rb = (slice(k * per, (k + 1) * per) for k in range(4))
    assert np.all(m.wi[tf, 2] > 0) and np.all(m.wo[tf, 2] < 0)  # front = +z
    assert np.all(m.wi[tb, 2] < 0) and np.all(m.wo[tb, 2] > 0)
    assert np.all(m.wi[rf, 2] > 0) and np.all(m.wo[rf, 2] > 0)
    assert np.all(m.wi[rb, 2] < 0) and np.all(m.wo[rb, 2] < 0)
    diag = np.arange(145) * 145 + np.arange(145)  # row o = column i
    # transmission diagonal = straight through, reflection diagonal = mirror direction
    for blk in (tf, tb):
        np.testing.assert_allclose(m.wo[blk][diag], -m.wi[blk][diag], atol=1e-12)
    for blk in (rf, rb):
        np.testing.assert_allclose(m.wo[blk][diag], m.wi[blk][diag] * [-1, -1, 1], atol=1e-12)
    assert m.value[tf][0] == 2.063833 and m.lines[tf][0] == 108


@pytest.mark.parametrize("blocks, expected", [
    ("front", ["Transmission Front", "Reflection Front"]),
    ("back", ["Transmission Back", "Reflection Back"]),
    ("reflection", ["Reflection Front", "Reflection Back"]),
    ("Reflection Back", ["Reflection Back"]),
    (("transmission front", "Reflection Front"), ["Transmission Front", "Reflection Front"]),
])
def test_block_choice(blocks, expected):
    m = klems.read_klems(REAL, blocks=blocks)
    assert m.metadata["blocks"].split(", ") == expected
    assert m.n == len(expected) * 2 * 145 * 145


def test_bad_choices():
    with pytest.raises(FitlabError, match="'Sideways'"):
        klems.read_klems(REAL, blocks="Sideways")
    with pytest.raises(InputFileError, match="no channel UV"):
        klems.read_klems(REAL, channels="UV")


# --------------------------------------------------------------------------------------------
# Synthetic files
# --------------------------------------------------------------------------------------------


def test_lambertian_hemispherical_sums_are_exact(lambert_xml):
    kf = klems.read_klems_file(lambert_xml)
    assert detect_format(lambert_xml).name == "klems"
    (basis,) = kf.bases.values()
    assert basis.n == N_QUARTER
    checks = klems.energy_checks(kf)["Visible"]
    assert checks["Reflection Front"]["hemispherical"]["min"] == pytest.approx(0.6, abs=1e-6)
    assert checks["Transmission Front"]["hemispherical"]["max"] == pytest.approx(0.2, abs=1e-6)
    assert checks["T+R Front"]["max"] == pytest.approx(0.8, abs=1e-6)
    assert checks["T+R Back"]["max"] == pytest.approx(0.5, abs=1e-6)


def test_bounds_worked_back_from_90_and_builtin_basis(tmp_path):
    a = klems.read_klems_file(_write(tmp_path, klems_xml(_lambert_blocks())))
    b = klems.read_klems_file(_write(tmp_path, klems_xml(_lambert_blocks(), with_bounds=False)))
    c = klems.read_klems_file(_write(tmp_path, klems_xml(_lambert_blocks(), define_basis=False)))
    for other in (b, c):
        x, y = a.blocks[0].incident, other.blocks[0].incident
        np.testing.assert_allclose(y.ring_lower, x.ring_lower)
        np.testing.assert_allclose(y.ring_upper, x.ring_upper)
        np.testing.assert_allclose(y.ring_theta, x.ring_theta)


def test_rows_layout_is_transposed(tmp_path):
    rng = np.random.default_rng(0)
    mat = rng.uniform(0.01, 0.1, size=(N_QUARTER, N_QUARTER))
    cols = klems.read_klems_file(_write(tmp_path, klems_xml({("Visible", "Reflection Front"): mat})))
    rows = klems.read_klems_file(_write(tmp_path, klems_xml({("Visible", "Reflection Front"): mat.T},
                                                            structure="Rows")))
    np.testing.assert_array_equal(cols.blocks[0].matrix, rows.blocks[0].matrix)
    # Columns: text row = outgoing patch, column = incident patch
    m = klems.measurement_from_klems(cols)
    i_patch, o_patch = 3, 17
    row = o_patch * N_QUARTER + i_patch
    assert m.value[row] == pytest.approx(mat[o_patch, i_patch])
    basis = cols.blocks[0].incident
    assert m.theta_i[row] == basis.theta[i_patch]
    assert m.phi_i[row] == pytest.approx((basis.phi[i_patch] + 180) % 360)
    assert (m.theta_o[row], m.phi_o[row]) == (basis.theta[o_patch], basis.phi[o_patch])


def test_nanometre_channels(tmp_path):
    text = klems_xml({("Visible", "Reflection Front"): np.full((41, 41), 0.1)})
    text = text.replace('<Wavelength unit="Integral">Visible</Wavelength>',
                        '<Wavelength unit="Nanometer">550</Wavelength>')
    m = klems.read_klems(_write(tmp_path, text))
    assert m.channel_names == ("550nm",) and m.wavelength_nm.tolist() == [550.0]


# --------------------------------------------------------------------------------------------
# Broken files
# --------------------------------------------------------------------------------------------


def _write(tmp_path, text, name=None):
    name = name or f"f{len(list(tmp_path.iterdir()))}.xml"
    path = tmp_path / name
    path.write_text(text)
    return path


def _line_of(text, fragment, nth=0):
    pos = -1
    for _ in range(nth + 1):
        pos = text.index(fragment, pos + 1)
    return text.count("\n", 0, pos) + 1


def _good():
    return klems_xml(_lambert_blocks())


def test_malformed_xml(tmp_path):
    text = _good().replace("</Material>", "", 1)
    with pytest.raises(InputFileError, match="not well-formed XML: mismatched tag") as info:
        klems.read_klems(_write(tmp_path, text))
    assert info.value.line is not None


def test_non_numeric_token_names_its_line(tmp_path):
    good = _good()
    lines = good.split("\n")
    target = _line_of(good, "<ScatteringData>") + 3  # third text row of the first block
    lines[target - 1] = lines[target - 1].replace("0.190985932", "0.19x", 1)
    with pytest.raises(InputFileError) as info:
        klems.read_klems(_write(tmp_path, "\n".join(lines)))
    assert info.value.line == target and "'0.19x'" in str(info.value)
    assert "Visible Reflection Front" in str(info.value)


def test_wrong_row_length(tmp_path):
    good = _good()
    lines = good.split("\n")
    target = _line_of(good, "<ScatteringData>") + 5
    lines[target - 1] = lines[target - 1].split(", ", 1)[1]  # drop one value: 40 of 41
    with pytest.raises(InputFileError) as info:
        klems.read_klems(_write(tmp_path, "\n".join(lines)))
    assert info.value.line == target and "this line has 40 values, expected 41" in str(info.value)


def test_wrong_matrix_size_on_one_line(tmp_path):
    mat = np.full((N_QUARTER, N_QUARTER), 0.1)
    text = klems_xml({("Visible", "Reflection Front"): mat}).replace(",\n", ", ")
    text = text.replace("0.1, 0.1, 0.1,", "0.1, 0.1,", 1)
    with pytest.raises(InputFileError, match="holds 1680 values, expected 41×41 = 1681"):
        klems.read_klems(_write(tmp_path, text))


@pytest.mark.parametrize("edit, fragment", [
    (lambda t: t.replace("<WavelengthData>", "<Ignored>").replace("</WavelengthData>", "</Ignored>"),
     "no <Layer> with <WavelengthData>"),
    (lambda t: t.replace("<ColumnAngleBasis>LBNL/Klems Quarter", "<ColumnAngleBasis>Custom", 1),
     "angle basis 'Custom' is not defined"),
    (lambda t: t.replace(">Columns<", ">TensorTree3<"), "bsdf2klems"),
    (lambda t: t.replace("WindowElement", "Something"), "not <WindowElement>"),
    (lambda t: t.replace("Transmission Back", "Sideways Back"), "'Sideways Back' is unknown"),
    (lambda t: t.replace("Transmission Back", "Transmission Front"), "appears twice"),
    (lambda t: t.replace("0.190985932", "-0.19", 1), "is not a finite non-negative BSDF"),
    (lambda t: t.replace("0.190985932", "nan", 1), "is not a finite non-negative BSDF"),
    (lambda t: t.replace("<nPhis>8</nPhis>", "<nPhis>8.5</nPhis>", 1), "not a whole number"),
    # issue 13: an OverflowError, and a header sizing an allocation
    (lambda t: t.replace("<nPhis>8</nPhis>", "<nPhis>1e30</nPhis>", 1), "it must be >= 1 and <= 4096"),
    (lambda t: t.replace("<nPhis>8</nPhis>", "<nPhis>inf</nPhis>", 1), "a finite number"),
    (lambda t: t.replace("<UpperTheta>27</UpperTheta>", "<UpperTheta>28</UpperTheta>", 1),
     "do not tile"),
])
def test_broken_files(tmp_path, edit, fragment):
    path = _write(tmp_path, edit(_good()))
    with pytest.raises(InputFileError) as info:
        klems.read_klems(path)
    assert fragment in str(info.value) and str(path) in str(info.value)


def test_missing_block_requested(tmp_path):
    path = _write(tmp_path, klems_xml({("Visible", "Reflection Front"): np.full((41, 41), 0.1)}))
    with pytest.raises(InputFileError, match="has no Transmission Front block"):
        klems.read_klems(path, blocks="Transmission Front")
    with pytest.raises(InputFileError, match="has no Transmission Front, Transmission Back block"):
        klems.read_klems(path, blocks="transmission")
    assert klems.read_klems(path, blocks="front").n == 41 * 41  # a group takes what is there


def test_cli_error_exit(tmp_path, capsys):
    path = _write(tmp_path, _good().replace("</Material>", "", 1))
    assert main(["info", str(path)]) == 2
    err = capsys.readouterr().err
    assert "not well-formed XML" in err and str(path) in err


# --------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------


def test_cli_info_convert_fit(tmp_path, capsys):
    assert main(["info", str(REAL), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "klems" and info["rows"] == 8 * 145 * 145
    assert info["energy_checks"]["Visible"]["T+R Front"]["at_most_1"] is True
    assert info["angle_bases"]["LBNL/Klems Full"]["patches"] == 145
    assert main(["info", str(REAL)]) == 0
    assert "direct_part_normal_incidence: 0.048894" in capsys.readouterr().out

    out = tmp_path / "shade.csv"
    assert main(["convert", str(REAL), str(out)]) == 0
    back = read_measurement(out)
    m = read_any(REAL)
    assert back.n == m.n and back.channel_names == ("Visible", "Solar")
    np.testing.assert_allclose(back.value, m.value, rtol=1e-9)
    np.testing.assert_allclose(back.wo, m.wo, atol=1e-9)

    fit = tmp_path / "fit.json"
    assert main(["fit", str(REAL), "--model", "lambertian", "--channel", "Visible",
                 "--fit-subset", "theta_i == 0 and theta_o < 90", "--starts", "1", "--quiet",
                 "--out", str(fit)]) == 0
    rec = json.loads(fit.read_text())
    # the front reflection at normal incidence is uniform: albedo = π · 0.153571
    assert rec["fits"][0]["parameters"]["albedo"]["value"] == pytest.approx(np.pi * 0.153571,
                                                                             rel=1e-6)
