"""``fitlab.write_report``: the HTML report of a fit or of a model comparison, from Python, as
``fitlab report FIT.json --out DIR`` and ``fitlab compare ... --out DIR`` write them."""

from __future__ import annotations

from pathlib import Path

from fitlab.fitting.compare import CompareResult
from fitlab.fitting.result import FitResult
from fitlab.report.build import build_report
from fitlab.report.compare import build_compare_report


def write_report(result, out_dir, *, data=None, chain=None, renderers: bool = False,
                 progress: bool = False) -> dict:
    """Write the report page ``index.html`` and its figures into ``out_dir``; returns the
    report's summary (``index``: the page).

    ``result``: a :class:`~fitlab.FitResult` (not yet saved: saved there first as ``fit.json``
    and ``chain.npz``), a parameter file's path, a ``fitlab fit-maps`` folder (its map report,
    fitlab/report/texture_maps.py), or a :class:`~fitlab.CompareResult` (its tables
    saved there first if they are not). For a fit, ``data`` and ``chain`` name its measurement
    and chain files when the record does not find them, and ``renderers`` adds the hand-off
    section (``fitlab report --renderers``)."""
    out_dir = Path(out_dir)
    from fitlab.report.texture_maps import build_maps_report, is_maps_folder

    if isinstance(result, (str, Path)) and is_maps_folder(result):  # a fitlab fit-maps folder
        return build_maps_report(result, out_dir, progress=progress)
    if isinstance(result, CompareResult):
        if result.path is None or Path(result.path).resolve() != out_dir.resolve():
            result = result.save(out_dir)
        return build_compare_report(result, out_dir, progress=progress)
    if not isinstance(result, FitResult):  # a parameter file
        return build_report(result, out_dir, data_path=data, chain_path=chain,
                            renderers=renderers, progress=progress)
    res = result
    if res.path is None:
        out_dir.mkdir(parents=True, exist_ok=True)
        res = res.save(out_dir / "fit.json", chain=(out_dir / "chain.npz") if res.chains else None)
    if data is None and res.measurement is not None:
        data = res.measurement.path
    if chain is None and res.chains and res.record.get("chain"):
        chain = Path(res.path).parent / res.record["chain"]["path"]
    return build_report(res.path, out_dir, data_path=data, chain_path=chain,
                        renderers=renderers, progress=progress)
