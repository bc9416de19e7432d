"""The accuracy-cost study of the repository (issue 20): ``fitlab tradeoffs`` on the reference
materials, one report folder each under reports/accuracy_cost/, and reports/accuracy_cost/
README.md summarising them (every number read from the runs' tradeoffs.json).

    .venv/bin/python benchmarks/accuracy_cost.py [--quick] [--only NAME]

Materials: the Walter rough-glass fit, the brown-vinyl Lambertian + GGX conductor fit, the
brown-vinyl Weidlich–Wilkie fit (a layered fit) and the SpongeCake preset "fabric".
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "reports" / "accuracy_cost"
#: (folder, what, the CLI arguments after `fitlab tradeoffs`)
STUDIES = (
    ("walter_rough_glass", "Walter rough-glass fit (GGX rough dielectric, BTDF data)",
     ["fits/walter_rough_glass.json"]),
    ("brown_vinyl_lambert_ggx_conductor", "brown vinyl: Lambertian + GGX conductor fit",
     ["fits/brown_vinyl_lambert_ggx_conductor.json"]),
    ("brown_vinyl_weidlich_wilkie", "brown vinyl: Weidlich–Wilkie (Lambertian base) fit, layered",
     ["fits/brown_vinyl_weidlich_wilkie_lambert.json"]),
    ("spongecake_fabric", "SpongeCake preset fabric (two volumetric layers, R, G, B)",
     ["--preset", "fabric"]),
)
BEGIN, END = "<!-- accuracy_cost:begin -->", "<!-- accuracy_cost:end -->"


def _fmt(x):
    return "—" if x is None else f"{x:.2g}"


def summary(name: str, what: str, args: list, doc: dict) -> str:
    v = doc["variants"]

    def pick(knob, setting=None, current=None):
        for x in v:
            if x["knob"] == knob and (setting is None or x["setting"] == setting) and \
                    (current is None or x["current"] == current):
                return x
        return None
    lines = [f"### [{what}]({name}/index.html)", "",
             f"`fitlab tradeoffs {' '.join(args)} --out reports/accuracy_cost/{name}/`"
             + (" (--quick)" if doc["quick"] else ""), "",
             f"Scored on {doc['directions']}; the run took {doc['seconds']:.0f} s.", ""]
    rows = []
    p32 = pick("precision", "float32")
    if p32:
        rows.append(("float32 instead of float64", _fmt(p32["errors"]["f_rel_rms"]),
                     f"{p32['seconds'] * 1e3:.3g} ms vs "
                     f"{pick('precision', 'float64')['seconds'] * 1e3:.3g} ms per 1e5 evaluations"))
    for knob in ("Fresnel", "G1 (Beckmann)", "coat inter-reflections", "thin-layer masking",
                 "thin-layer bounces K"):
        for x in v:
            if x["knob"] == knob and not x["current"] and x["errors"].get("f_rel_rms"):
                rows.append((f"{knob}: {x['setting']}", _fmt(x["errors"]["f_rel_rms"]),
                             f"{x['seconds'] * 1e3:.3g} ms per 1e5 evaluations"))
    for x in v:
        if x["knob"] == "layered physics":
            rows.append((f"vs the simulator: {x['setting']}", _fmt(x["errors"]["f_rel_rms"]),
                         f"{x['seconds'] * 1e3:.3g} ms per 1e5 evaluations; simulation "
                         f"{x['cost']['simulation_seconds']:.0f} s, its noise "
                         f"{_fmt(x['errors']['simulation_rel_rms'])}"))
    for x in v:
        if x["knob"] == "simulator paths":
            rows.append((f"simulator, {x['setting']} per incidence (its 1σ error)",
                         _fmt(x["errors"]["f_rel_rms"]), f"{x['seconds']:.2g} s per simulation"))
    tabs = [x for x in v if x["knob"] == "tables" and x["errors"]]
    if tabs:
        for x in sorted(tabs, key=lambda x: x["errors"]["f_rel_rms"])[:2] + \
                sorted(tabs, key=lambda x: x["cost"]["bytes"])[:1]:
            rows.append((f"table {x['setting']} ({x['cost']['bytes'] // 1024} KiB)",
                         _fmt(x["errors"]["f_rel_rms"]),
                         f"bake {x['seconds']:.3g} s; SSIM {x['errors']['ssim']:.4f}"))
    for x in v:
        if x["knob"] == "MCMC length":
            rows.append((f"MCMC {x['setting']}",
                         f"width {_fmt(x['errors']['interval_width_rel_dev'])}",
                         f"{x['seconds']:.1f} s per fit; ESS {x['errors']['ess']:.0f}"))
    lines += ["| knob: setting | relative RMS error of f·cos (MCMC: interval width) | time |",
              "|---|---|---|"] + [f"| {a} | {b} | {c} |" for a, b, c in rows] + [""]
    lines += [f"- **{k}**: {r}" for k, r in doc["recommendations"].items()] + [""]
    if doc["skipped"]:
        lines.append("Not applicable: " + "; ".join(f"{k} ({r})" for k, r in
                                                    doc["skipped"].items()) + ".")
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only", action="append")
    a = ap.parse_args(argv)
    import fitlab

    docs = {}
    for name, what, args in STUDIES:
        out = OUT / name
        if a.only and name not in a.only:
            if (out / "tradeoffs.json").is_file():
                docs[name] = json.loads((out / "tradeoffs.json").read_text())
            continue
        print(f"== {name}", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        if args[0] == "--preset":
            fitlab.tradeoffs(preset=args[1], out=out, quick=a.quick, progress=True)
        else:
            fitlab.tradeoffs(ROOT / args[0], out=out, quick=a.quick, progress=True)
        print(f"== {name}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
        docs[name] = json.loads((out / "tradeoffs.json").read_text())
    machine = next(iter(docs.values()))["machine"] if docs else {}
    body = [BEGIN, "",
            f"Measured {time.strftime('%Y-%m-%d')} on {machine.get('cores')} CPUs "
            f"({machine.get('cpu')}), {platform.system()}, Python {machine.get('python')}, JAX "
            f"{machine.get('jax')} by `python benchmarks/accuracy_cost.py`. Times are this "
            "machine's; errors depend only on the material, its data and the seed.", ""]
    for name, what, args in STUDIES:
        if name in docs:
            body.append(summary(name, what, args, docs[name]))
    body.append(END)
    readme = OUT / "README.md"
    text = readme.read_text() if readme.is_file() else ""
    block = "\n".join(body)
    if BEGIN in text and END in text:
        text = text[:text.index(BEGIN)] + block + text[text.index(END) + len(END):]
    else:
        text = HEAD + block + "\n"
    from fitlab.io.atomic import atomic_write_text

    atomic_write_text(readme, text)
    print(f"wrote {readme.relative_to(ROOT)}", file=sys.stderr)
    return 0


HEAD = """# What accuracy costs: `fitlab tradeoffs` on the reference materials

Each folder is one run of `fitlab tradeoffs` (data_formats/tradeoffs_json.md): `index.html`
(the Pareto plot of error against time per knob, the table of every measured setting, one
recommendation per use case), `tradeoffs.json` (every number) and `pareto.png`/`.svg`. Remake
all of them and this summary with `python benchmarks/accuracy_cost.py`. It replaces the scattered
figures: the simulator's standard error against time is the `simulator paths` knob of each
layered material; the detailed study of every LUT kind stays in
[`data_formats/lut_exr.md`](../../data_formats/lut_exr.md) ("Accuracy",
[`reports/lut_accuracy/`](../lut_accuracy/)), this one tabulates each material's own BRDF.

"""

if __name__ == "__main__":
    sys.exit(main())
