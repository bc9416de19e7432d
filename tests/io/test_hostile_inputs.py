"""Hostile and malformed inputs for every file format fitlab reads (issue 13).

Each test takes a valid file (real data, a bundled example or one of fitlab's own outputs),
makes every variant the generators in ``tests/hostile.py`` make of it (truncations, flipped
bytes, wrong encodings, NaN / Inf / huge / negative / non-numeric numbers in data and header
fields, deleted and repeated lines, declared sizes that do not match, deep nesting, wrong JSON
types, a folder in place of the file) and runs the fitlab commands that read that format on
each. Every run must keep the contract of ``hostile.run_contract``: exit 0 or 2, never a
traceback, on failure a short message naming the file and nothing written, on success no NaN
or infinity written, the input untouched, no allocation sized by a header.

The quick tier runs a deterministic sample of the cases of each format (every ``QUICK_EVERY``-th
case, and every case the generators mark ``allocation``); the slow tier (CI) runs them all.
"""

from __future__ import annotations

import itertools
import os
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest

import hostile as H

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "data_formats" / "examples"
SHARED = ROOT.parent / "shared" / "data"
QUICK_EVERY = 9


def _shared(rel: str) -> Path:
    p = SHARED / rel
    if not p.is_file():
        from conftest import skip_or_fail

        skip_or_fail(f"{p} is not here (the shared data folder sits beside the repository)")
    return p


def _pgii_seed() -> bytes:
    """The first 1,500 points of the real pgII scan with its whole header (a valid file)."""
    lines = _shared("tekari_pgII/golden_glossy_paper_pgII_theta26.84.txt").read_bytes().split(b"\n")
    head = [line for line in lines[:80] if line.startswith(b"#")]
    body = lines[len(head):len(head) + 1500]
    head = [b"#datapoints_in_file\t1500" if h.startswith(b"#datapoints_in_file") else h for h in head]
    return b"\n".join(head + body) + b"\n"


def _merl_seed() -> bytes:
    """A valid MERL table (a smooth synthetic BRDF): the 12-byte header and 3 x 1,458,000 doubles."""
    from fitlab.io import merl

    th = np.linspace(0.0, 1.0, merl.N_THETA_H)[:, None, None]
    f = 0.3 + 5.0 * np.exp(-20 * th ** 2) + np.zeros(merl.DIMS)
    raw = np.stack([f / s for s in merl.SCALES])
    return struct.pack("<3i", *merl.DIMS) + raw.astype("<f8").tobytes()


def _merl_cases(data: bytes):
    from fitlab.io import merl

    n = len(data)
    yield H.Case("empty", b"")
    yield H.Case("folder", H.FOLDER)
    yield H.Case("truncated_by_one", data[:-1])
    yield H.Case("truncated_header", data[:7])
    yield H.Case("extra_byte", data + b"\x00")
    yield H.Case("declares_huge", struct.pack("<3i", 90000, 9000, 1800) + data[12:], allocation=True)
    yield H.Case("declares_negative", struct.pack("<3i", -90, 90, 180) + data[12:])
    body = np.frombuffer(data, dtype="<f8", offset=12).copy()
    for name, change in (("all_invalid", lambda b: b.fill(-1.0)), ("one_nan", lambda b: b.__setitem__(n // 16, np.nan)),
                         ("one_inf", lambda b: b.__setitem__(7, np.inf)), ("one_huge", lambda b: b.__setitem__(11, 1e308)),
                         ("all_zero", lambda b: b.fill(0.0))):
        b = body.copy()
        change(b)
        yield H.Case(name, data[:12] + b.tobytes())
    del merl


def _rgl_cases(data: bytes):
    """Byte-level damage, and field tables that lie: the field count, a name length, a rank, a
    data type code, an offset and a shape rewritten in place (a tensor_file's declared sizes)."""
    yield from H.byte_cases(data, text=False)
    from fitlab.io.rgl import HEADER_BYTES, parse_tensor_file

    tf = parse_tensor_file(data)
    yield H.Case("field_count_2^32-1", data[:14] + struct.pack("<I", 2 ** 32 - 1) + data[18:])
    for name, fld in list(tf.fields.items())[:4]:
        start = fld.header_offset
        name_len = struct.unpack_from("<H", data, start)[0]
        rank_at = start + 2 + name_len
        ndim = struct.unpack_from("<H", data, rank_at)[0]
        shape_at = rank_at + 2 + 1 + 8

        def put(fmt, at, value, _d=data):
            b = bytearray(_d)
            struct.pack_into(fmt, b, at, value)
            return bytes(b)

        yield H.Case(f"{name}:name_len_65535", put("<H", start, 65535))
        yield H.Case(f"{name}:rank_65535", put("<H", rank_at, 65535))
        yield H.Case(f"{name}:dtype_99", put("<B", rank_at + 2, 99))
        yield H.Case(f"{name}:offset_2^63", put("<Q", rank_at + 3, 2 ** 63))
        yield H.Case(f"{name}:offset_in_header", put("<Q", rank_at + 3, HEADER_BYTES))
        if ndim:
            yield H.Case(f"{name}:shape_2^40", put("<Q", shape_at, 2 ** 40), allocation=True)
            yield H.Case(f"{name}:shape_0", put("<Q", shape_at, 0))


def _xml_cases(data: bytes):
    """Text damage plus XML's own hazards: entity expansion (billion laughs), an external
    entity naming a system file, a DOCTYPE, deep element nesting, a huge nPhis."""
    yield from H.byte_cases(data)
    yield from H.text_cases(data, positions=2)
    head, _, body = data.partition(b"?>")
    laughs = (b'<!DOCTYPE x [<!ENTITY a "aaaaaaaaaa">' + b"".join(
        f'<!ENTITY {chr(98 + k)} "{("&" + chr(97 + k) + ";") * 10}">'.encode() for k in range(9))
        + b"]>")
    yield H.Case("billion_laughs", head + b"?>" + laughs + body.replace(b"<Layer>", b"<Layer>&j;", 1))
    yield H.Case("external_entity", head + b'?><!DOCTYPE x [<!ENTITY e SYSTEM "file:///etc/passwd">]>'
                 + body.replace(b"<Layer>", b"<Layer>&e;", 1))
    yield H.Case("deep_elements", head + b"?>" + b"<a>" * 200_000 + b"</a>" * 200_000)
    yield H.Case("nphis_huge", data.replace(b"<nPhis>8</nPhis>", b"<nPhis>99999999999</nPhis>", 1))


def _exr_cases(data: bytes):
    """Byte-level damage, and headers that lie: written with the OpenEXR binding."""
    yield from H.byte_cases(data, text=False)
    import OpenEXR

    src = EXAMPLES / "lut_fresnel_copper.exr"
    f = OpenEXR.File(str(src), separate_channels=True)
    header, channels = dict(f.header()), {k: c.pixels for k, c in f.channels().items()}
    changes = {
        "axes_deep": ("fitlab.axes", "[" * 20000 + "]" * 20000),
        "axes_not_json": ("fitlab.axes", "{"),
        "axes_mapping_list": ("fitlab.axes", header["fitlab.axes"].replace('"linear"', '["linear"]', 1)),
        "axes_size_huge": ("fitlab.axes", header["fitlab.axes"].replace('"size": 128', '"size": 4096000', 1)),
        "axes_size_text": ("fitlab.axes", header["fitlab.axes"].replace('"size": 128', '"size": "128"', 1)),
        "axes_lo_nan": ("fitlab.axes", header["fitlab.axes"].replace('"lo": 0.0', '"lo": NaN', 1)),
        "channels_wrong": ("fitlab.channels", '["Q"]'),
        "channels_object": ("fitlab.channels", '{"a": 1}'),
        "kind_unknown": ("fitlab.kind", "x" * 5000),
        "dtype_wrong": ("fitlab.dtype", "double"),
        "params_list": ("fitlab.params", "[]"),
        "accuracy_deep": ("fitlab.accuracy", "[" * 5000 + "]" * 5000),
        "version_wrong": ("fitlab.schema_version", "99"),
        "schema_missing": ("fitlab.schema", None),
    }
    tmp = Path(os.environ.get("TMPDIR", "/tmp"))
    for name, (key, value) in changes.items():
        h = dict(header)
        if value is None:
            h.pop(key, None)
        else:
            h[key] = value
        out = tmp / f"fitlab-hostile-{os.getpid()}-{name}.exr"
        try:
            OpenEXR.File(h, {k: OpenEXR.Channel(v) for k, v in channels.items()}).write(str(out))
            payload = out.read_bytes()
        finally:
            out.unlink(missing_ok=True)
        yield H.Case(name, payload)


def _sweep_seed() -> bytes:
    """The example sweep with few paths per point, its scene named as ``../coated_lambertian.toml``
    (each case is written one folder below the test's folder, where SUPPORT copies the scene).
    The seed holds no path of this machine, so the cases picked are the same on every machine."""
    text = (EXAMPLES / "sweeps" / "coated_lambertian_grid.toml").read_text()
    return text.replace('"../scenes/coated_lambertian.toml"', '"../coated_lambertian.toml"') \
        .replace("samples = 4000", "samples = 32").encode()


# format: (seed loader, case generator, suffix, commands)
FORMATS = {
    "measurement_csv": (lambda: (EXAMPLES / "walter_rough_glass.csv").read_bytes(),
                        lambda d: itertools.chain(H.byte_cases(d), H.text_cases(d)), ".csv",
                        ["info", "convert", "fit"]),
    "measurement_csv_rgb": (lambda: (EXAMPLES / "measurement_rgb_sigma.csv").read_bytes(),
                            lambda d: itertools.chain(H.byte_cases(d), H.text_cases(d)), ".csv",
                            ["info", "convert"]),
    "zemax": (lambda: (EXAMPLES / "zemax_brown_vinyl.bsdf").read_bytes(),
              lambda d: itertools.chain(H.byte_cases(d), H.text_cases(d)), ".bsdf",
              ["info", "convert"]),
    "rgl": (lambda: _shared("rgl_epfl_via_fzy28/aurora_white_rgb.bsdf").read_bytes(),
            _rgl_cases, ".bsdf", ["info", "convert"]),
    "klems": (lambda: _shared("lbnl_bsdfxmlparser/2011-SA1.XML").read_bytes(),
              _xml_cases, ".xml",
              ["info", "convert"]),
    "pgii": (_pgii_seed, lambda d: itertools.chain(H.byte_cases(d), H.text_cases(d)), ".txt",
             ["info", "convert"]),
    "merl": (_merl_seed, _merl_cases, ".binary", ["info", "convert"]),
    "spectral_scan": (lambda: (EXAMPLES / "spectral_scan.csv").read_bytes(),
                      lambda d: itertools.chain(H.byte_cases(d), H.text_cases(d)), ".csv",
                      ["info", "info_quantity", "convert_quantity"]),
    "openmaterial": (lambda: (EXAMPLES / "openmaterial" / "example_material_lidar_brdf.xompt")
                     .read_bytes(),
                     lambda d: itertools.chain(H.byte_cases(d), H.json_cases(d, depth=4)),
                     ".xompt", ["info", "convert"]),
    "directions_csv": (lambda: (EXAMPLES / "directions_inplane.csv").read_bytes(),
                       lambda d: itertools.chain(H.byte_cases(d), H.text_cases(d)), ".csv", ["eval"]),
    "fit_json": (lambda: (ROOT / "fits" / "walter_rough_glass.json").read_bytes(),
                 lambda d: itertools.chain(H.byte_cases(d), H.json_cases(d, depth=3)), ".json",
                 ["info", "lut", "convert_fit", "report"]),
    "fit_json_rgb": (lambda: (ROOT / "fits" / "rgl_aurora_white_coated_lambert.json").read_bytes(),
                     lambda d: itertools.chain(H.byte_cases(d), H.json_cases(d, depth=3)), ".json",
                     ["info", "lut"]),
    "chain_npz": (lambda: (ROOT / "fits" / "walter_rough_glass_chain.npz").read_bytes(),
                  lambda d: itertools.chain(H.npz_cases(d), H.byte_cases(d, text=False)), ".npz",
                  ["report_chain"]),
    "lut_exr": (lambda: (EXAMPLES / "lut_fresnel_copper.exr").read_bytes(), _exr_cases, ".exr",
                ["info", "report_lut"]),
    "scene_toml": (lambda: (EXAMPLES / "scenes" / "measurement_directions.toml").read_bytes(),
                   lambda d: itertools.chain(H.byte_cases(d), H.text_cases(d)), ".toml", ["simulate"]),
    "scene_toml_sggx": (lambda: (EXAMPLES / "scenes" / "sggx_fiber_layer.toml").read_bytes(),
                        lambda d: itertools.chain(H.byte_cases(d), H.text_cases(d)), ".toml",
                        ["simulate"]),
    "sweep_toml": (_sweep_seed, lambda d: itertools.chain(H.byte_cases(d), H.text_cases(d)),
                   ".toml", ["sweep"]),
}

#: Files a format's cases name relative to themselves: copied into the test's folder, the parent
#: of every case's folder (tests/hostile.py: fresh).
SUPPORT = {"sweep_toml": [EXAMPLES / "scenes" / "coated_lambertian.toml"]}

FIT = ROOT / "fits" / "walter_rough_glass.json"
COMMANDS = {
    "info": lambda s, o: ["info", s],
    "convert": lambda s, o: ["convert", s, o / "x.csv"],
    "convert_fit": lambda s, o: ["convert", s, o / "t.bsdf"],
    "info_quantity": lambda s, o: ["info", s, "--quantity", "radiance_factor"],
    "convert_quantity": lambda s, o: ["convert", s, o / "x.csv", "--quantity", "radiance_factor"],
    "fit": lambda s, o: ["fit", s, "--model", "rough_dielectric", "--starts", "2", "--quiet",
                         "--out", o / "f.json"],
    "eval": lambda s, o: ["eval", "rough_conductor", "--param", "alpha=0.3", "--param", "n=1.5",
                          "--param", "k=2", "--directions", s, "--out", o / "v.csv"],
    "lut": lambda s, o: ["lut", "model", "--from-fit", s, "--size", "8x8", "--phi-d", "slice",
                         "--no-shader",
                         "--check-points", "16", "--quiet", "--out", o / "t.exr"],
    "report": lambda s, o: ["report", s, "--data", EXAMPLES / "walter_rough_glass.csv", "--quiet",
                            "--no-lut-discovery", "--out", o / "r"],
    "report_chain": lambda s, o: ["report", FIT, "--chain", s, "--quiet", "--no-lut-discovery",
                                  "--out", o / "r"],
    "report_lut": lambda s, o: ["report", FIT, "--lut", s, "--quiet", "--out", o / "r"],
    "simulate": lambda s, o: ["simulate", s, "--samples", "32", "--quiet", "--out", o / "s.csv"],
    "sweep": lambda s, o: ["simulate", "--sweep", s, "--out-dir", o / "sw", "--workers", "1",
                           "--quiet"],
}
#: Commands that build a whole report or simulation on success: run on a sample even in CI.
COSTLY = {"report": 25, "report_chain": 1, "report_lut": 2, "simulate": 1, "fit": 6,
          "convert_fit": 4, "sweep": 4}
#: Formats whose seed is large (MB): every n-th case even in the whole suite.
LARGE = {"klems": 3, "pgii": 2}
#: Commands run in the whole suite only (each successful case compiles and fits).
SLOW_COMMANDS = {"fit"}
#: Seeds too large for the quick tier.
SLOW_FORMATS = {"klems", "fit_json_rgb", "scene_toml_sggx", "merl"}


def _params():
    for fmt, (_, _, _, commands) in FORMATS.items():
        for cmd in commands:
            for tier in ("quick", "all"):
                # the quick sample is a subset of the whole run's cases: not run beside it
                marks = [pytest.mark.slow] if tier == "all" else [pytest.mark.sample_of_slow]
                if tier == "quick" and (fmt in SLOW_FORMATS or cmd in SLOW_COMMANDS):
                    continue
                yield pytest.param(fmt, cmd, tier, marks=marks, id=f"{fmt}-{cmd}-{tier}")


@pytest.mark.parametrize("fmt, command, tier", list(_params()))
def test_hostile_inputs(fmt, command, tier, tmp_path, monkeypatch):
    load, generate, suffix, _ = FORMATS[fmt]
    monkeypatch.chdir(ROOT)  # fit files name their data relative to themselves; keep cwd fixed
    data = load()
    for support in SUPPORT.get(fmt, []):
        shutil.copyfile(support, tmp_path / support.name)
    cases = list(generate(data))
    assert len({c.name for c in cases}) == len(cases), "case names must be unique"
    every = QUICK_EVERY if tier == "quick" else 1
    every *= COSTLY.get(command, 1) * LARGE.get(fmt, 1)
    picked = [c for k, c in enumerate(cases) if k % every == 0 or c.allocation]
    breaches = []
    for case in picked:
        src, out = H.fresh(tmp_path, case, suffix)
        o = H.run_contract(COMMANDS[command](src, out), src, out, allocation=case.allocation)
        if o.problems:
            breaches.append(f"{case.name}: {'; '.join(o.problems)}")
    assert not breaches, f"{len(breaches)} of {len(picked)} {fmt} cases broke the contract " \
        f"under `fitlab {command}`:\n" + "\n".join(breaches[:20])


def test_generators_are_broad():
    """The generators make every category the issue lists, for text and binary formats alike."""
    csv = list(H.byte_cases(b"a,b\n1,2\n3,4\n")) + list(H.text_cases(b"# k: 1\na,b\n1,2\n3,4\n"))
    names = " ".join(c.name for c in csv)
    for category in ("empty", "folder", "truncated", "flipped", "non_utf8", "utf16", "nul_bytes",
                     "long_line", "_nan", "_inf", "1e308", "_abc", "field", "deleted", "doubled",
                     "header_only"):
        assert category in names, category
    js = " ".join(c.name for c in H.json_cases(b'{"a": {"b": [1, 2]}}'))
    for category in ("a:deleted", "a.b:null", "a.b.0:x", "deep_nesting", "not_an_object"):
        assert category in js, category
    assert any(c.allocation for c in H.npz_cases((ROOT / "fits" / "walter_rough_glass_chain.npz").read_bytes()))


def test_contract_catches_breaches(tmp_path):
    """The contract check itself fails on a traceback, a long message, a message without the
    file's name and output written on failure (so the tests above can fail)."""
    src = tmp_path / "x.csv"
    src.write_text("theta_i\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / "partial.csv").write_text("1\n")
    o = H.run_contract(["info", src], src, out)
    assert o.status == 2 and any("wrote" in p for p in o.problems)
    o = H.run_contract(["convert", tmp_path / "missing-dir", out / "y.csv"], src, out)
    assert any("does not name the file" in p for p in o.problems)
