"""BSDF value files written by ``fitlab eval``: the direction columns plus ``value`` (the BSDF f
in 1/sr, without cosine) and ``#`` metadata naming model, parameters and conventions. The
columns and ``# quantity: bsdf`` line follow the measurement CSV, so the file reads back as data.
Spec: data_formats/values_csv.md."""

from __future__ import annotations

import io
from fitlab.version import __version__



def format_values_csv(pairs, values, *, model, params, options, source, dtype) -> str:
    out = io.StringIO()
    out.write("# fitlab eval output (data_formats/values_csv.md)\n")
    out.write("# quantity: bsdf\n")
    out.write("# unit: 1/sr (BSDF f without cosine)\n")
    out.write(f"# model: {model}\n")
    out.write("# parameters: " + ", ".join(f"{k}={float(v)!r}" for k, v in params.items()) + "\n")
    out.write("# options: " + (", ".join(f"{k}={v}" for k, v in options.items()) or "none") + "\n")
    out.write(f"# directions: {source}\n")
    out.write(f"# precision: {dtype}\n")
    out.write(f"# fitlab_version: {__version__}\n")
    out.write("# conventions: data_formats/CONVENTIONS.md\n")
    out.write("theta_i,phi_i,theta_o,phi_o,value\n")
    for row in zip(pairs.theta_i, pairs.phi_i, pairs.theta_o, pairs.phi_o, values):
        out.write(",".join(f"{x:.10g}" for x in row[:4]) + f",{float(row[4]):.9e}\n")
    return out.getvalue()
