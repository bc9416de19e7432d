"""What LUT accuracy costs: for each table kind, resolution × axis mapping × half/float →
max and RMS relative error of the table read as the shader reads it (bilinear lookup of the
stored values, ``fitlab.lut.lookup``, identical to the generated GLSL per tests/lut/test_lut_glsl.py)
against direct evaluation at random points, the EXR file size in bytes, and the bake time.
All variants of a kind are measured at the same points: equal parts uniform in the texture
coordinates of each mapping the study uses for that kind.

Bake time: evaluating every sample (float64), warm (a first, untimed call at the same size
compiles), median of two runs for the fast kinds, one run for the quadrature kinds. The direct
evaluations at the random points are shared between half and float variants.

Writes the table between the markers of data_formats/lut_exr.md (section "What accuracy
costs"), the rows as reports/lut_accuracy/lut_accuracy.json and the figure
reports/lut_accuracy/lut_accuracy.png (fitlab.report.lut_figures).

The φd study (``--phi-d``, or ``--phi-d-only`` to run it alone): the model table of reference
fits in 2D (the φd = 90° slice) and with a φd axis of 8, 16 and 32 samples: the
parameterization error (lookup at the coordinates of random direction pairs vs the model at those
pairs, the measure ``--phi-d auto`` decides by), the interpolation error, file size and the
warm evaluation time of every sample. Written between the lut_phi_d markers of
data_formats/lut_exr.md and as reports/lut_accuracy/phi_d.json.

Usage: python benchmarks/lut_accuracy.py [--quick] [--no-write] [--phi-d | --phi-d-only]
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import fitlab
from fitlab import lut
from fitlab.export import exr

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "data_formats" / "lut_exr.md"
OUT = ROOT / "reports" / "lut_accuracy"
BEGIN, END = "<!-- lut_accuracy:begin -->", "<!-- lut_accuracy:end -->"
PHI_BEGIN, PHI_END = "<!-- lut_phi_d:begin -->", "<!-- lut_phi_d:end -->"
FIT = ROOT / "fits" / "walter_rough_glass.json"
#: Direction pairs of the φd study's parameterization error (the same pairs for every table).
PHI_D_PAIRS = 16384


def configs(quick: bool):
    """(kind label, spec factory kwargs, label, n_check) per study row."""
    glass = {f["channel"]: {k: v["value"] for k, v in f["parameters"].items() if k in ("alpha", "eta")}
             for f in json.loads(FIT.read_text())["fits"]}
    sizes2 = (64, 128, 256, 512) if not quick else (64, 128)
    for n in sizes2:
        for mc in ("u8", "linear"):
            for ma in ("linear", "log"):
                yield ("D (ggx)", dict(kind="D", size=(n, n), mappings=(mc, ma)),
                       f"cos {mc}, alpha {ma}", 4096)
    for n in ((32, 128, 512) if not quick else (32, 128)):
        for m in ("linear", "sqrt"):
            yield ("fresnel (copper)", dict(kind="fresnel", size=(n,), mappings=(m,),
                                            params=lut.conductor_preset("copper")), f"cos {m}", 4096)
            yield ("fresnel (glass 1.5)", dict(kind="fresnel", size=(n,), mappings=(m,),
                                               params={"Y": {"eta": 1.5}}), f"cos {m}", 4096)
    for n in ((16, 32, 64) if not quick else (16, 32)):
        for ma in ("linear", "sqrt"):
            yield ("albedo_conductor", dict(kind="albedo_conductor", size=(n, n),
                                            mappings=("linear", ma)), f"alpha {ma}", 256)
            yield ("dfg", dict(kind="dfg", size=(n, n), mappings=("linear", ma)), f"alpha {ma}", 256)
    for n in ((8, 16) if not quick else (8,)):
        yield ("albedo_dielectric", dict(kind="albedo_dielectric", size=(n, n, n // 2)),
               "linear", 24)
    for n in ((64, 128, 256) if not quick else (64,)):
        for mc in ("u8", "linear"):
            yield ("model (Walter glass fit)", dict(kind="model", model="rough_dielectric",
                                                   params=glass, size=(n, n),
                                                   mappings=(mc, "linear")), f"cos_h {mc}", 4096)
            yield ("model (conductor a=0.05)", dict(
                kind="model", model="rough_conductor", size=(n, n), mappings=(mc, "linear"),
                params={"Y": {"alpha": 0.05, "n": 0.2, "k": 3.9}}), f"cos_h {mc}", 4096)


class _Memo:
    """Memoize a spec's evaluate by the coordinates (half and float share the evaluations)."""

    def __init__(self, fn):
        self.fn, self.cache = fn, {}

    def __call__(self, coords):
        key = coords.tobytes()
        if key not in self.cache:
            self.cache[key] = self.fn(coords)
        return self.cache[key]


def pooled_points(quick):
    """One point set per kind, shared by all its variants: equal parts uniform in the texture
    coordinates of each mapping the study uses for that kind (so no mapping is measured only
    where it is dense)."""
    by_kind = {}
    for kind_label, kw, _, n_check in configs(quick):
        spec = lut.make_spec(kw["kind"], **{k: v for k, v in kw.items() if k != "kind"})
        by_kind.setdefault(kind_label, (n_check, {}))[1][tuple(a.mapping for a in spec.axes)] = spec.axes
    out = {}
    rng = np.random.default_rng(0)
    for kind_label, (n_check, variants) in by_kind.items():
        per = max(1, n_check // len(variants))
        pts = []
        for axes in variants.values():
            t = rng.random((per, len(axes)))
            pts.append(np.stack([a.to_x(t[:, k]) for k, a in enumerate(axes)], axis=-1))
        out[kind_label] = np.concatenate(pts)
    return out


def study(quick: bool, progress=lambda s: print(s, file=sys.stderr)):
    rows = []
    points = pooled_points(quick)
    with tempfile.TemporaryDirectory() as tmp:
        for kind_label, kw, label, n_check in configs(quick):
            kind = kw.pop("kind")
            spec = lut.make_spec(kind, **kw)
            memo = _Memo(spec.evaluate)
            spec = spec._replace(evaluate=memo)
            coords = lut.grid_coords(spec.axes)
            fast = kind in ("D", "fresnel", "model")
            memo.fn(coords)  # the first call at this size compiles: not timed
            times = []
            for _ in range(2 if fast else 1):
                t = time.perf_counter()
                result = memo.fn(coords)
                times.append(time.perf_counter() - t)
            bake_s = float(np.median(times))
            memo.cache[coords.tobytes()] = result
            for dtype in ("half", "float"):
                try:
                    table = lut.bake(spec, dtype, check_points=0)
                    table.accuracy["interpolation"] = lut.measure_accuracy(
                        table, spec.evaluate, 0, points=points[kind_label])
                except ValueError as exc:  # e.g. half overflow
                    rows.append({"kind": kind_label, "label": label, "dtype": dtype,
                                 "size": "x".join(str(a.size) for a in spec.axes),
                                 "error": str(exc)})
                    progress(f"{kind_label:28s} {label:22s} {dtype:5s}: {exc}")
                    continue
                path = Path(tmp) / "t.exr"
                exr.write_exr(path, table)
                acc = table.accuracy["interpolation"]
                row = {"kind": kind_label, "label": label, "dtype": dtype,
                       "size": "x".join(str(a.size) for a in table.axes),
                       "texels": int(np.prod(table.values.shape[:2])),
                       "channels": len(table.channels), "size_bytes": os.path.getsize(path),
                       "max_rel": acc["max_rel"], "rms_rel": acc["rms_rel"],
                       "storage_max_rel": table.accuracy["storage"]["max_rel"],
                       "quadrature_max_abs": (table.accuracy.get("quadrature") or {}).get(
                           "max_abs_error_estimate"),
                       "points": acc["points"], "bake_s": bake_s}
                rows.append(row)
                progress(f"{kind_label:28s} {label:22s} {row['size']:>9s} {dtype:5s}: max "
                         f"{row['max_rel']:.2e}  RMS {row['rms_rel']:.2e}  {row['size_bytes']:8d} B"
                         f"  {bake_s * 1e3:8.1f} ms")
    return rows


def markdown(rows, machine):
    out = [f"Measured {_dt.date.today().isoformat()} on {machine} by `python "
           "benchmarks/lut_accuracy.py` (fitlab " + fitlab.__version__ + "). Errors: relative, "
           "floor 1e-3 of the channel maximum, over `points` random points, the same for every "
           "variant of a kind (equal parts uniform in the texture coordinates of each mapping "
           "compared); `quad.` is the stored quadrature error estimate (absolute); bake time is "
           "the warm evaluation of every sample (on a 2-core machine other jobs may share: times "
           "are indicative).", "",
           "| kind | variant | size | type | max rel | RMS rel | points | bytes | bake (ms) | quad. |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            out.append(f"| {r['kind']} | {r['label']} | {r['size']} | {r['dtype']} | "
                       f"refused: {r['error'].split(';')[0]} | | | | | |")
            continue
        q = "" if r["quadrature_max_abs"] is None else f"{r['quadrature_max_abs']:.1e}"
        out.append(f"| {r['kind']} | {r['label']} | {r['size']} | {r['dtype']} | "
                   f"{r['max_rel']:.2e} | {r['rms_rel']:.2e} | {r['points']} | {r['size_bytes']} | "
                   f"{r['bake_s'] * 1e3:.1f} | {q} |")
    return "\n".join(out)


def phi_d_configs(quick: bool):
    """(label, make_spec kwargs) of the φd study: reference fits and a conductor."""
    from fitlab.export.lut_files import from_fit

    def fit(name):
        model, options, params = from_fit(ROOT / "fits" / name)
        return dict(model=model, options=options, params=params)

    tables = [("brown vinyl, Weidlich–Wilkie (Lambert) fit",
               fit("brown_vinyl_weidlich_wilkie_lambert.json")),
              ("brown vinyl, Lambert + GGX conductor fit",
               fit("brown_vinyl_lambert_ggx_conductor.json")),
              ("Walter rough glass fit (reflection)", fit("walter_rough_glass.json")),
              ("rough conductor α = 0.3", dict(model="rough_conductor",
                                               params={"Y": {"alpha": 0.3, "n": 0.2, "k": 3.9}}))]
    sizes = [(256, 256), (256, 256, 8), (256, 256, 16), (256, 256, 32)]
    if quick:
        tables, sizes = tables[:1], [(64, 64), (64, 64, 8)]
    for label, kw in tables:
        for size in sizes:
            yield label, dict(kw, size=size)


def phi_d_study(quick: bool, progress=lambda s: print(s, file=sys.stderr)):
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, kw in phi_d_configs(quick):
            spec = lut.make_spec("model", **kw)
            coords = lut.grid_coords(spec.axes)
            spec.evaluate(coords)  # compiles (not timed)
            times = []
            for _ in range(2):
                t = time.perf_counter()
                spec.evaluate(coords)
                times.append(time.perf_counter() - t)
            lut.bake(spec, "half", check_points=4096)  # compiles the checks (not timed)
            t = time.perf_counter()
            table = lut.bake(spec, "half", check_points=4096)
            bake_total = time.perf_counter() - t
            par = lut.kinds.parameterization_error(table, spec, PHI_D_PAIRS)
            path = Path(tmp) / "t.exr"
            exr.write_exr(path, table)
            size = "x".join(str(a.size) for a in table.axes)
            row = {"table": label, "size": size, "dtype": "half",
                   "texels": int(np.prod(table.values.shape[:2])),
                   "param_rms_rel": par["rms_rel"], "param_max_rel": par["max_rel"],
                   "pairs": par["points"], "meets_target": par["meets_target"],
                   "interp_rms_rel": table.accuracy["interpolation"]["rms_rel"],
                   "interp_max_rel": table.accuracy["interpolation"]["max_rel"],
                   "size_bytes": os.path.getsize(path), "eval_s": float(np.median(times)),
                   "bake_s": bake_total}
            rows.append(row)
            progress(f"{label:45s} {size:>11s}: param RMS {row['param_rms_rel']:.2e} max "
                     f"{row['param_max_rel']:.2e} | interp RMS {row['interp_rms_rel']:.2e} | "
                     f"{row['size_bytes']:9d} B | eval {row['eval_s']:.2f} s, bake "
                     f"{row['bake_s']:.2f} s")
    return rows


def phi_d_markdown(rows, machine):
    t = lut.PHI_D_TARGET
    out = [f"Measured {_dt.date.today().isoformat()} on {machine} by `python "
           "benchmarks/lut_accuracy.py --phi-d-only` (fitlab " + fitlab.__version__ + "), half "
           f"tables. Parameterization error: lookup at the coordinates of {PHI_D_PAIRS} random "
           "direction pairs of the upper hemisphere (uniform in solid angle, the same pairs for "
           "every table) vs the model at those pairs, relative, floor 1e-3 of the largest f "
           f"over the pairs; `auto` target: RMS ≤ {t['rms_rel']:g} and max ≤ {t['max_rel']:g}. "
           "Interpolation error: lookup vs the model at 4096 random points uniform in texture "
           "coordinates (floor 1e-3 of the table's largest value; for a 3D table most of these "
           "points lie beyond the horizon, where the table holds the horizon value). `eval`: "
           "warm evaluation of every sample (median of two); `bake`: `fitlab.lut.bake` with its "
           "accuracy checks, warm (storage rounding and the checks at 4096 points included); "
           "times are indicative on a shared 2-core machine.", "",
           "| table | size | texels | param. RMS rel | param. max rel | meets target | "
           "interp. RMS rel | bytes | eval (ms) | bake (s) |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['table']} | {r['size']} | {r['texels']} | {r['param_rms_rel']:.2e} | "
                   f"{r['param_max_rel']:.2e} | {'yes' if r['meets_target'] else 'no'} | "
                   f"{r['interp_rms_rel']:.2e} | {r['size_bytes']} | {r['eval_s'] * 1e3:.0f} | "
                   f"{r['bake_s']:.2f} |")
    return "\n".join(out)


def _replace_between(begin, end, text):
    doc = DOC.read_text()
    i, j = doc.index(begin) + len(begin), doc.index(end)
    DOC.write_text(doc[:i] + "\n" + text + "\n" + doc[j:])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer sizes (a smoke run)")
    ap.add_argument("--no-write", action="store_true", help="print only")
    ap.add_argument("--phi-d", action="store_true", help="also run the model table's φd study")
    ap.add_argument("--phi-d-only", action="store_true", help="run the φd study only")
    a = ap.parse_args(argv)
    machine = (f"{os.cpu_count()} CPUs ({platform.machine()}), {platform.system()}, "
               f"Python {platform.python_version()}")
    if a.phi_d or a.phi_d_only:
        t0 = time.perf_counter()
        rows = phi_d_study(a.quick)
        print(f"phi_d study took {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        text = phi_d_markdown(rows, machine)
        print(text)
        if not a.no_write:
            OUT.mkdir(parents=True, exist_ok=True)
            (OUT / "phi_d.json").write_text(json.dumps({"machine": machine, "rows": rows},
                                                       indent=1, ensure_ascii=False) + "\n")
            _replace_between(PHI_BEGIN, PHI_END, text)
            print(f"wrote {OUT / 'phi_d.json'} and the φd table in {DOC}", file=sys.stderr)
        if a.phi_d_only:
            return 0
    t0 = time.perf_counter()
    rows = study(a.quick)
    print(f"study took {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    text = markdown(rows, machine)
    print(text)
    if a.no_write:
        return 0
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "lut_accuracy.json").write_text(json.dumps({"machine": machine, "rows": rows},
                                                      indent=1) + "\n")
    from fitlab.report.lut_figures import lut_accuracy_figure

    lut_accuracy_figure([r for r in rows if "error" not in r], OUT / "lut_accuracy.png")
    _replace_between(BEGIN, END, text)
    print(f"wrote {OUT / 'lut_accuracy.png'}, {OUT / 'lut_accuracy.json'} and the table in {DOC}",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
