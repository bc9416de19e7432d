"""fitlab's own JSON formats as published JSON Schemas (data_formats/schemas/): the published
copies are the package's, every schema is a valid draft 2020-12 schema, every committed file of a
format is valid against its schema, and every invalid example is refused naming its field. The
export records are JSON inside other files: the glTF exports' ``materials[0].extras.fitlab`` and
the LUT OpenEXR header's ``fitlab.*`` attributes (fitlab.export.exr.header_record)."""

import json
from pathlib import Path

import jsonschema
import pytest

from fitlab.errors import InputFileError
from fitlab.io import validate as V

ROOT = Path(__file__).resolve().parents[2]
PUBLISHED = ROOT / "data_formats" / "schemas"
INVALID = ROOT / "data_formats" / "examples" / "invalid"

#: The format a record names (its "schema" or, for tradeoffs, "format") -> fitlab's schema name.
FORMATS = {"fitlab-fit": "fit", "fitlab-compare": "compare", "fitlab-tradeoffs": "tradeoffs",
           "fitlab-maps": "maps", "fitlab-completion": "completion",
           "fitlab-layered-atlas": "layered_atlas"}
#: The glTF exports' extras.fitlab record: its "spec" -> fitlab's schema name.
GLTF_SPECS = {"data_formats/gltf_material.md": "gltf_material",
              "data_formats/stack.md": "gltf_maps"}
#: Every schema fitlab publishes: the JSON files' and the export records' (the LUT header).
SCHEMAS = {*FORMATS.values(), *GLTF_SPECS.values(), "lut"}
#: Committed files of a format that are not records of it, and why.
NOT_RECORDS = {"gltf_material_invalid.gltf": "the Khronos validator's invalid example "
               "(data_formats/gltf_material.md): its extras.fitlab holds a note, not a conversion"}


def test_published_schemas_are_the_packaged_ones_and_valid_schemas():
    published = sorted(p.name for p in PUBLISHED.glob("*.schema.json"))
    packaged = sorted(p.name for p in V.SCHEMA_DIR.glob("*.schema.json"))
    assert published == packaged == sorted(f"{n}.schema.json" for n in SCHEMAS)
    for name in published:
        assert (PUBLISHED / name).read_bytes() == (V.SCHEMA_DIR / name).read_bytes(), name
        schema = json.loads((PUBLISHED / name).read_text(encoding="utf-8"))
        jsonschema.Draft202012Validator.check_schema(schema)
        assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"


def _gltf_record(path):
    """(schema name, record) of a glTF export: its material's extras.fitlab, named by its spec."""
    doc = json.loads(path.read_text(encoding="utf-8"))
    rec = doc["materials"][0]["extras"]["fitlab"]
    return GLTF_SPECS[rec["spec"]], rec


def _lut_record(path):
    """("lut", the header record) of a LUT OpenEXR file, its JSON attributes parsed."""
    from fitlab.export.exr import _open, header_record

    return "lut", header_record(path, _open(path, header_only=True).header())


def _record(path):
    """(schema name, record) of a file of one of fitlab's formats, or None."""
    if path.suffix == ".gltf":
        return _gltf_record(path)
    if path.suffix == ".exr":
        return _lut_record(path)
    rec = json.loads(path.read_text(encoding="utf-8"))
    tag = rec.get("schema", rec.get("format")) if isinstance(rec, dict) else None
    return (FORMATS[tag], rec) if tag in FORMATS else None


def _committed_records():
    """(path, schema name, record) of every committed file that holds one of fitlab's records:
    JSON files that name their format, glTF exports, LUT OpenEXR files (not fitlab's other
    EXR images: its maps, whose header is not a LUT's)."""
    from fitlab.export.exr import PREFIX

    for folder in ("fits", "data_formats/examples", "reports"):
        for path in sorted(p for p in (ROOT / folder).rglob("*")
                           if p.suffix in (".json", ".gltf", ".exr")):
            if path.parent == INVALID or path.name in NOT_RECORDS:
                continue
            if path.suffix == ".exr":
                import OpenEXR

                with OpenEXR.File(str(path), header_only=True) as f:
                    if f.header().get(PREFIX + "schema") != "fitlab-lut":
                        continue
            found = _record(path)
            if found is not None:
                yield path, *found


def test_every_committed_record_is_valid_against_its_schema():
    seen = {}
    for path, name, rec in _committed_records():
        # fitlab's validator is draft 2020-12 with stricter number and integer types: what it
        # accepts, any draft 2020-12 validator accepts
        V.check_schema(rec, name, path)
        seen[name] = seen.get(name, 0) + 1
    assert {"fit", "compare", "tradeoffs", "gltf_material", "lut"} <= set(seen), seen
    assert seen["lut"] >= 2, seen  # the Fresnel and the thin-layer examples


def test_the_map_fit_gltf_record_is_valid_against_its_schema():
    """The map fit's glTF hand-off (fitlab/export/gltf_maps.py), of a conversion made up here
    (no fit): its material's extras.fitlab is valid against gltf_maps.schema.json."""
    import numpy as np

    from fitlab.export.gltf_maps import gltf_maps
    from fitlab.fitting.maps import MapsResult

    status = np.zeros((2, 3), int)
    val = lambda v, k=1: np.full((2, 3, k), v)  # noqa: E731
    conv = MapsResult("gltf_pbr", {}, {}, ("R", "G", "B"),
                      {"base_color": val(0.5, 3), "metallic": val(1.0),
                       "roughness_factor": val(0.25), "specular": val(0.8)}, {}, (),
                      np.zeros((2, 3, 3)), status, {}, None, [], 0.0)
    doc, _ = gltf_maps(conv, "lambertian+rough_conductor")
    rec = doc["materials"][0]["extras"]["fitlab"]
    assert GLTF_SPECS[rec["spec"]] == "gltf_maps"
    V.check_schema(json.loads(json.dumps(rec)), "gltf_maps", "material.gltf")


#: Each invalid example: how fitlab reads it, what the message says, and whether the schema alone
#: refuses it (the others break a rule the reader checks after the schema).
def _read_fit(p):
    from fitlab.export.paramfile import read_fit

    return read_fit(p)


def _load_compare(p):
    from fitlab.fitting.compare.result import load_compare

    return load_compare(p)


def _read_lut(p):
    from fitlab.export.exr import read_exr

    return read_exr(p)


def _load_atlas(p):
    from fitlab.atlas.region import load

    return load(p)


def _check_gltf(p):
    name, rec = _gltf_record(p)
    return V.check_schema(rec, name, p)


INVALID_EXAMPLES = {
    "fit_matrix_entry_string.json": (_read_fit, "field fits[0].covariance.matrix[1][0] is a "
                                     "string; expected a finite number or null", True),
    "fit_missing_channel.json": (_read_fit, "field fits[0].channel is missing", True),
    "fit_covariance_not_square.json": (_read_fit, "field fits[0].covariance.matrix is not 2 x 2",
                                       False),
    "compare_no_channels.json": (_load_compare, "field channels is missing", True),
    "tradeoffs_error_not_a_number.json": (
        lambda p: V.check_schema(json.loads(p.read_text(encoding="utf-8")), "tradeoffs", p),
        "field variants[0].errors.f_rel_rms is a string", True),
    # published only: fitlab reads no glTF back; another tool validates the record
    "gltf_material_relative_rms_text.gltf": (
        _check_gltf, "field conversion.relative_rms is a string; expected a finite number",
        True),
    "gltf_maps_ior_text.gltf": (_check_gltf, "field fixed.ior is a string; expected a finite "
                                "number", True),
    "layered_atlas_within_text.json": (_load_atlas, "field entries[0].within[0][1] is a "
                                       "string; expected true or false", True),
    "layered_atlas_short_grid.json": (_load_atlas, "field entries[0].within is not 2 x 2", False),
    # the LUT header: the schema's refusals and those of the code before and after it (None:
    # the file has no header to check)
    "lut_axis_size_text.exr": (_read_lut, "field fitlab.axes[0].size is a string; expected a "
                               "whole number. fitlab.axes[0].size: the number of samples", True),
    "lut_wrong_version.exr": (_read_lut, "has schema_version '2'; this fitlab reads version 1",
                              True),
    "lut_plain.exr": (_read_lut, "not a fitlab lookup table", True),
    "lut_truncated.exr": (_read_lut, "damaged or truncated", None),
    "lut_nan.exr": (_read_lut, "channel holds 1 NaN or Inf values", False),
    "lut_thin_layer_axes.exr": (_read_lut, "a 3-axis thin_layer table has the axes mu, kappa1, "
                                "kappa2, the header declares mu, alpha, kappa2", False),
}


def _schema_of_name(name: str) -> str | None:
    """The schema an invalid example's name starts with (``gltf_maps_...``: gltf_maps)."""
    return max((n for n in SCHEMAS if name.startswith(f"{n}_")), key=len, default=None)


def test_invalid_examples_are_refused_naming_the_field():
    names = {p.name for p in INVALID.iterdir() if p.suffix in (".json", ".gltf", ".exr")
             and _schema_of_name(p.name)}
    assert names == set(INVALID_EXAMPLES)
    for name, (read, fragment, by_schema) in INVALID_EXAMPLES.items():
        path = INVALID / name
        with pytest.raises(InputFileError) as e:
            read(path)
        assert str(e.value).startswith(f"{path}: ") and fragment in str(e.value), str(e.value)
        if by_schema is None:
            continue
        schema, rec = _record(path)
        assert schema == _schema_of_name(name), name
        valid = jsonschema.Draft202012Validator(V.load_schema(schema)).is_valid(rec)
        assert valid is not by_schema, name


def test_the_lut_reader_exits_2_on_an_invalid_header(tmp_path, capsys):
    """`fitlab info` of a LUT whose header the schema refuses: exit status 2, the file, the
    field and what to do; no traceback."""
    from fitlab.cli import main

    path = INVALID / "lut_axis_size_text.exr"
    assert main(["info", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}: field fitlab.axes[0].size is a string" in err
    assert "write the table again with `fitlab lut`" in err and "Traceback" not in err


def test_the_fit_schema_lists_the_readers_choices():
    """The parameter file's read_options enums are the reader's own (fitlab/io/gates.py)."""
    from fitlab.io.gates import ANGLES, GATES, QUANTITIES

    ro = V.load_schema("fit")["properties"]["data"]["properties"]["read_options"]["properties"]
    assert ro["angles"]["enum"] == list(ANGLES) and ro["quantity"]["enum"] == list(QUANTITIES)
    assert ro["accept"]["items"]["enum"] == list(GATES)


def test_the_lut_schema_lists_the_readers_choices():
    """The LUT header's enums and bounds are the reader's own (fitlab/lut/axes.py)."""
    from fitlab.lut import MAPPINGS, SCHEMA, SCHEMA_VERSION, SIZE_MAX, SIZE_MIN

    props = V.load_schema("lut")["properties"]
    axis = props["fitlab.axes"]["items"]["properties"]
    assert axis["mapping"]["enum"] == list(MAPPINGS)
    assert (axis["size"]["minimum"], axis["size"]["maximum"]) == (SIZE_MIN, SIZE_MAX)
    assert props["fitlab.schema"]["const"] == SCHEMA
    assert props["fitlab.schema_version"]["const"] == str(SCHEMA_VERSION)
