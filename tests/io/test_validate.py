"""The shared validation layer (fitlab/io/validate.py): each concern on its own."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest

from fitlab.errors import InputFileError
from fitlab.io import validate as V


def test_quote_is_short_and_one_line():
    q = V.quote("x" * 10_000)
    assert len(q) < 80 and "10000 characters" in q
    assert V.quote(b"\xff\xfeab") == repr("\\xff\\xfeab")
    assert V.quote("ab") == "'ab'"


@pytest.mark.parametrize("raw, fragment, line", [
    ("é".encode("utf-16"), "UTF-16 or UTF-32", None),
    (b"a\nb\x00c", "NUL byte (byte 3)", 2),
    (b"ok\nok\n\xff", "byte 6", 3),
])
def test_decode_text_names_line_and_byte(raw, fragment, line):
    with pytest.raises(InputFileError) as e:
        V.decode_text("f.txt", raw, what="CSV", encoding="utf-8")
    assert fragment in str(e.value) and e.value.line == line


def test_decode_text_fallback():
    assert V.decode_text("f", "é".encode("latin-1"), what="x", fallback="latin-1") == "é"


@pytest.mark.parametrize("token, fragment", [
    ("nan", "not a finite number"), ("1e999", "not a finite number"), ("abc", "not a number"),
    ("", "(empty) is not a number"), ("9" * 400, "not a finite number"), ("-1", "must be >= 0"),
])
def test_parse_number(token, fragment):
    with pytest.raises(InputFileError, match=None) as e:
        V.parse_number(token, "f", what="eta", lo=0)
    assert fragment in str(e.value) and len(str(e.value)) < 200
    assert V.parse_number(" 2.5 ", "f", lo=0) == 2.5


def test_counts_and_allocations_are_bounded(monkeypatch):
    assert V.check_count("12", "f", what="n", present=12) == 12
    with pytest.raises(InputFileError, match="holds only 5"):
        V.check_count(6, "f", what="n", present=5)
    with pytest.raises(InputFileError, match="not a whole number"):
        V.check_count("1e400", "f", what="n")
    with pytest.raises(InputFileError, match="more than the"):
        V.check_allocation((1 << 20, 1 << 20), "f", what="table")
    monkeypatch.setenv(V.MAX_VALUES_ENV, "100")
    assert V.max_values() == 100
    with pytest.raises(InputFileError, match="FITLAB_MAX_VALUES"):
        V.check_count(101, "f", what="n")
    with pytest.raises(InputFileError, match="bytes are present"):
        V.check_allocation((10,), "f", what="a", present_bytes=79)


def test_json_depth_and_constants():
    with pytest.raises(InputFileError, match="nests too deeply"):
        V.load_json("f", b"[" * 100_000 + b"]" * 100_000, what="fit file")
    with pytest.raises(InputFileError, match="nests too deeply"):
        V.load_json("f", b"[" * 40 + b"]" * 40, what="fit file")
    with pytest.raises(InputFileError, match="NaN is not a JSON number"):
        V.load_json("f", b'{"a": NaN}', what="fit file")
    assert V.load_json("f", b'{"a": [1, 2]}', what="x") == {"a": [1, 2]}
    with pytest.raises(InputFileError, match="not valid TOML"):
        V.load_toml("f", b"a = = 1", what="scene")


def test_schema_names_the_field():
    """fitlab's JSON Schemas through jsonschema: the first error names the field in fitlab's
    spelling, what is wrong, and (the schema's description, then the caller's hint) what to do."""
    import copy
    import json
    from pathlib import Path

    good = json.loads((Path(__file__).resolve().parents[2] / "fits" / "walter_rough_glass.json")
                      .read_text(encoding="utf-8"))
    assert V.check_schema(good, "fit", "f.json") is good

    def at(*keys_value):
        rec = copy.deepcopy(good)
        *keys, value = keys_value
        node = rec
        for k in keys[:-1]:
            node = node[k]
        if value is KeyError:
            del node[keys[-1]]
        else:
            node[keys[-1]] = value
        return rec

    fe = ("fits", 0, "statistics", "fit_error")
    cases = [(at("fits", []), "field fits has 0 entries; expected at least 1"),
             (at("fits", 0, "parameters", "alpha", "value", "1"),
              "field fits[0].parameters.alpha.value is a string; expected a finite number"),
             (at("fits", 0, "covariance", "matrix", 1, 0, "x"),
              "field fits[0].covariance.matrix[1][0] is a string; expected a finite number or null"),
             (at(*fe, "floor", -1), "field fits[0].statistics.fit_error.floor is -1; it must be >= 0"),
             (at("fits", 0, "channel", KeyError), "field fits[0].channel is missing"),
             (at(*fe, "floor_rule", "c"), "is 'c'; expected one of incidence_peak"),
             (at("fits", 0, "statistics", "n_fit", 1.0), "n_fit is a number; expected a whole number"),
             (at("fits", 0, "parameters", "alpha", "value", True), "is true/false"),
             (at("fits", 0, "parameters", "alpha", "value", float("inf")), "value is not a finite number"),
             (at("fits", 0, "parameters", "alpha", "value", 10 ** 400), "value is not a finite number"),
             (at("fits", 0, "parameters", "alpha", "bounds", [0]), "bounds has 1 entries; expected 2"),
             (at("model", "name", "x" * 10_001), "is a string of 10001 characters; at most 10000"),
             ([], "field at the top level is a list; expected an object")]
    for record, fragment in cases:
        with pytest.raises(InputFileError) as e:
            V.check_schema(record, "fit", "f.json", hint="do this")
        assert fragment in str(e.value) and str(e.value).startswith("f.json: field "), \
            (fragment, str(e.value))
        assert e.value.hint.endswith("do this")
    with pytest.raises(InputFileError) as e:
        V.check_schema(at("fits", 0, "channel", KeyError), "fit", "f.json", hint="do this")
    assert e.value.hint.startswith("fits[0].channel: the channel's name")


def _npz(members, compression=zipfile.ZIP_STORED):
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression) as zf:
        for name, blob in members.items():
            zf.writestr(name, blob)
    return buf.getvalue()


def _npy(arr, **kw):
    b = io.BytesIO()
    np.save(b, arr, **kw)
    return b.getvalue()


def test_read_npz_checks_each_member(tmp_path):
    ok = tmp_path / "ok.npz"
    ok.write_bytes(_npz({"a.npy": _npy(np.arange(6.0).reshape(2, 3)), "n.npy": _npy(np.array(["x"]))}))
    out = V.read_npz(ok, what="chain")
    assert out["a"].shape == (2, 3) and out["n"][0] == "x"
    bad = {
        "obj": ({"a.npy": _npy(np.array([{}], dtype=object), allow_pickle=True)}, "holds object values"),
        "huge": ({"a.npy": _npy(np.zeros(3)).replace(b"(3,)", b"(1099511627776,)".ljust(4))},
                 "more than the"),
        "short": ({"a.npy": _npy(np.zeros(100))[:-8]}, "is truncated (792 of 800 bytes)"),
        "notzip": (None, "is not a NumPy .npz archive"),
    }
    for name, (members, fragment) in bad.items():
        p = tmp_path / f"{name}.npz"
        p.write_bytes(b"not a zip" if members is None else _npz(members))
        with pytest.raises(InputFileError) as e:
            V.read_npz(p, what="chain")
        assert fragment in str(e.value), (name, str(e.value))
    blob = bytearray(_npz({"a.npy": _npy(np.arange(1000.0))}, zipfile.ZIP_DEFLATED))
    for k in range(60, 200, 7):
        blob[k] ^= 0x55
    p = tmp_path / "deflate.npz"
    p.write_bytes(bytes(blob))
    with pytest.raises(InputFileError, match="cannot be read|not a NumPy"):
        V.read_npz(p, what="chain")
