"""Registry of the files fitlab writes from data, a fit or a model (what ``fitlab convert``
reaches): each writer says which sources it takes (measured data as they are, a registry model,
a fit's parameter file), the settings it reads besides them, the file suffixes it goes with and
how to summarize what it wrote. Readers are the format registry (fitlab.io.formats); the
lookup tables of ``fitlab lut`` are the LUT kinds (fitlab.lut.KINDS)."""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from fitlab.export import merl, openmaterial, zemax
from fitlab.io.atomic import atomic_write_text
from fitlab.io.files import path_for_record
from fitlab.io.measurement import MEASURED, format_measurement_csv
from fitlab.registry import Registry


class Writer(NamedTuple):
    name: str
    title: str  # what the file is called in messages ("Zemax", "MERL")
    description: str
    suffixes: tuple  # lower-case output suffixes that choose this writer
    spec: str  # the data_formats/ document
    #: write_data(path, measurement, source, **settings) -> summary; None: measured data need
    #: a model first
    write_data: Callable | None
    #: write_model(path, model, params, options, **settings) -> summary; None: data only
    write_model: Callable | None
    #: write_fit(path, fit_path, channel=None, **settings) -> summary
    write_fit: Callable | None
    #: describe(summary) -> the line the command prints about the file written
    describe: Callable
    #: keyword settings of write_model / write_fit / write_data (each a `fitlab convert` flag)
    settings: tuple = ()
    #: complete(path, job, **settings) -> {"content": text or bytes, "filled": Filled, "marks",
    #: "grid", "grid_source", "notes"}: the data of a completion (fitlab.export.filling.Job)
    #: with the fit's values where they hold no reading (``fitlab convert --complete``; not
    #: written: fitlab.export.completion writes it with its record); None: not offered
    complete: Callable | None = None


def _write_csv(path, m, source) -> dict:
    text = format_measurement_csv(
        m, {"converted_from": f"{path_for_record(source, path)} ({m.file_quantity})"})
    atomic_write_text(path, text)
    return {"path": str(path), "rows": m.n, "channels": list(m.channel_names)}


def _complete_csv(path, job) -> dict:
    """A completion as a measurement CSV: the data's rows and gaps in file order, the fit's value
    where a row holds no reading or a replaced one, each row marked in the column completion."""
    from fitlab.export.filling import completed_rows, filled_rows

    rows, reason = completed_rows(job)
    text = format_measurement_csv(rows, {
        "converted_from": f"{path_for_record(job.m.path, path)} ({job.m.file_quantity})",
        "completed_by": f"fit {path_for_record(job.fit_path, path)} (model {job.fit.model}): "
                        f"{int(np.sum(reason != MEASURED))} values, marked in the column "
                        "completion (data_formats/completion_json.md)"}, completion=reason)
    return {"content": text, "filled": filled_rows(rows, reason),
            "marks": "in the file: its column completion", "grid": {"rows": rows.n},
            "grid_source": "the data's own rows", "notes": []}


def _describe_csv(s) -> str:
    return f"wrote {s['rows']} rows ({', '.join(s['channels'])}) to {s['path']}"


def _describe_zemax(s) -> str:
    g = s["grid"]
    return (f"wrote {s['path']}: Zemax {s['scatter']} of {s['model']} ({s['symmetry']}, "
            f"{'/'.join(s['channels'])}), {g['aoi']} AOI x {g['azimuth']} azimuth x "
            f"{g['radial']} radial angles; TIS {s['tis_range'][0]:.4g} .. {s['tis_range'][1]:.4g}")


def _describe_merl(s) -> str:
    g = s["grid"]
    return (f"wrote {s['path']}: MERL BRDF of {s['model']} ({'/'.join(s['channels'])}), "
            f"{g['theta_h']} theta_h x {g['theta_d']} theta_d x {g['phi_d']} phi_d bins, "
            f"{s['bins_with_value']} with a value; f {s['f_range'][0]:.4g} .. "
            f"{s['f_range'][1]:.4g} 1/sr")


WRITERS: Registry[Writer] = Registry("writer", {
    w.name: w
    for w in (
        Writer("csv", "measurement CSV", "fitlab measurement CSV of any file fitlab reads",
               (".csv",), "data_formats/measurement_csv.md", _write_csv, None, None,
               _describe_csv, complete=_complete_csv),
        Writer("zemax", "Zemax", "Zemax / Radiant IS-BSDF text tabulating a model or fit",
               (".bsdf",), "data_formats/zemax_bsdf.md", None, zemax.write_zemax,
               zemax.write_zemax_from_fit, _describe_zemax,
               ("grid", "aoi", "azimuth", "radial", "scatter"), complete=zemax.complete_zemax),
        Writer("merl", "MERL", "MERL BRDF binary (90x90x180 RGB) tabulating a model or fit",
               (".binary",), "data_formats/merl_binary.md", None, merl.write_merl,
               merl.write_merl_from_fit, _describe_merl, complete=merl.complete_merl),
        Writer("openmaterial", "OpenMATERIAL",
               "ASAM OpenMATERIAL 3D BRDF look-up table (JSON) sampling a model or fit on a "
               "grid, or holding measured data", (".xompt",), "data_formats/openmaterial_xompt.md",
               openmaterial.write_data, openmaterial.write_model, openmaterial.write_fit,
               openmaterial.describe, openmaterial.SETTINGS, complete=openmaterial.complete_data),
    )
})

#: The writer of an output whose suffix no writer claims.
DEFAULT = "csv"


def writer_for(path, name: str | None = None) -> Writer:
    """``name``'s writer if given, else the one claiming ``path``'s suffix, else DEFAULT's."""
    if name is not None:
        return WRITERS.get_entry(name)
    suffix = str(path).lower()
    for w in WRITERS.values():
        if any(suffix.endswith(s) for s in w.suffixes):
            return w
    return WRITERS[DEFAULT]


__all__ = ["Writer", "WRITERS", "DEFAULT", "writer_for"]
