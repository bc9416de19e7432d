"""fitlab's own JSON formats as published JSON Schemas (data_formats/schemas/): the published
copies are the package's, every schema is a valid draft 2020-12 schema, every committed file of a
format is valid against its schema, and every invalid example is refused naming its field."""

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
           "fitlab-maps": "maps", "fitlab-completion": "completion"}


def test_published_schemas_are_the_packaged_ones_and_valid_schemas():
    published = sorted(p.name for p in PUBLISHED.glob("*.schema.json"))
    packaged = sorted(p.name for p in V.SCHEMA_DIR.glob("*.schema.json"))
    assert published == packaged == sorted(f"{n}.schema.json" for n in FORMATS.values())
    for name in published:
        assert (PUBLISHED / name).read_bytes() == (V.SCHEMA_DIR / name).read_bytes(), name
        schema = json.loads((PUBLISHED / name).read_text(encoding="utf-8"))
        jsonschema.Draft202012Validator.check_schema(schema)
        assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"


def _committed_records():
    """(path, schema name) of every committed JSON file that names one of fitlab's formats."""
    for folder in ("fits", "data_formats/examples", "reports"):
        for path in sorted((ROOT / folder).rglob("*.json")):
            if path.parent == INVALID:
                continue
            rec = json.loads(path.read_text(encoding="utf-8"))
            tag = rec.get("schema", rec.get("format")) if isinstance(rec, dict) else None
            if tag in FORMATS:
                yield path, FORMATS[tag]


def test_every_committed_record_is_valid_against_its_schema():
    seen = {}
    for path, name in _committed_records():
        # fitlab's validator is draft 2020-12 with stricter number and integer types: what it
        # accepts, any draft 2020-12 validator accepts
        V.check_schema(json.loads(path.read_text(encoding="utf-8")), name, path)
        seen[name] = seen.get(name, 0) + 1
    assert {"fit", "compare", "tradeoffs"} <= set(seen), seen


#: Each invalid example: how fitlab reads it, what the message says, and whether the schema alone
#: refuses it (the others break a rule the reader checks after the schema).
def _read_fit(p):
    from fitlab.export.paramfile import read_fit

    return read_fit(p)


def _load_compare(p):
    from fitlab.fitting.compare.result import load_compare

    return load_compare(p)


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
}


def test_invalid_examples_are_refused_naming_the_field():
    names = {p.name for p in INVALID.glob("*.json") if p.name.split("_")[0] in
             {n for n in FORMATS.values()}}
    assert names == set(INVALID_EXAMPLES)
    for name, (read, fragment, by_schema) in INVALID_EXAMPLES.items():
        path = INVALID / name
        with pytest.raises(InputFileError) as e:
            read(path)
        assert str(e.value).startswith(f"{path}: ") and fragment in str(e.value), str(e.value)
        rec = json.loads(path.read_text(encoding="utf-8"))
        tag = rec.get("schema", rec.get("format"))
        valid = jsonschema.Draft202012Validator(V.load_schema(FORMATS[tag])).is_valid(rec)
        assert valid is not by_schema, name


def test_the_fit_schema_lists_the_readers_choices():
    """The parameter file's read_options enums are the reader's own (fitlab/io/gates.py)."""
    from fitlab.io.gates import ANGLES, GATES, QUANTITIES

    ro = V.load_schema("fit")["properties"]["data"]["properties"]["read_options"]["properties"]
    assert ro["angles"]["enum"] == list(ANGLES) and ro["quantity"]["enum"] == list(QUANTITIES)
    assert ro["accept"]["items"]["enum"] == list(GATES)
