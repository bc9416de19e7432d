"""``fitlab atlas`` in one call: the grids of :mod:`fitlab.atlas.grids` simulated and scored
(:mod:`fitlab.atlas.compute`), their verdicts (:mod:`fitlab.atlas.region`), the maps and page
(:mod:`fitlab.report.atlas`) written into one folder, and optionally the package data.

The files depend only on the inputs (models, grids, samples, seed, ``quick``), the simulator's
backend and fitlab's version: no dates, no run times, no paths of this machine. The run time is
printed, never written.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import NamedTuple

from fitlab.atlas import compute, grids, region

#: The source tree's root (where ``reports/`` lives in a checkout) and the page's folder there.
SOURCE_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_OUT = str(Path(region.PAGE).parent)
#: Seconds per model of compiling its bin estimator (and the simulator's first walk), for the
#: estimate printed before a run.
COMPILE_S = 5.0


class AtlasResult(NamedTuple):
    """What :func:`atlas` made: the record written (``record``), the output folder, the files
    written there, the package data file (None unless asked) and the wall time in seconds."""

    record: dict
    out: Path
    files: tuple
    package_data: Path | None
    seconds: float


def specs_for(models=None, *, quick=False, values=None, theta_i=None) -> list:
    """The grids of ``models`` (names; default every one), ``quick``-thinned, with the axes'
    ``values`` ({axis: [values]}, one model only) and the incidences ``theta_i`` replaced.
    ValueError with what to do for an unknown model or a bad override."""
    from fitlab.models import get_model

    def canonical(name):
        try:
            return get_model(name).name  # spaces and defaults written out or not
        except ValueError:
            return name  # GRIDS says what it knows

    names = [canonical(n) for n in models] if models else list(grids.GRIDS)
    specs = [grids.GRIDS.get_entry(n) for n in names]
    if values and len(specs) != 1:
        raise ValueError("--values changes one model's grid: give one --model with it")
    specs = [grids.quick(s) if quick else s for s in specs]
    return [grids.with_values(s, values, theta_i) for s in specs]


def estimate_s(specs, *, samples=None, quick=False) -> float:
    """Seconds the run should take on a 2-core CPU: each grid's measured cost per point (at the
    default sample counts; ``quick`` and small ``samples`` cost less) and its compilation."""
    total = 0.0
    for s in specs:
        n = len(s.axes[0].values) * len(s.axes[1].values)
        per = s.seconds_per_point * len(s.theta_i) / len(grids.THETA_I_DEG)
        if quick or (samples is not None and samples < compute.MAX_SAMPLES):
            cap = compute.QUICK_MAX_SAMPLES if quick else samples
            per *= max(cap / compute.MAX_SAMPLES, 0.1)
        total += n * per + COMPILE_S
    return total


def method() -> dict:
    """The constants that made the numbers (the record's ``method``)."""
    from fitlab.fitting.model_check import AIM_SE

    return {"theta_bins": grids.THETA_BINS, "phi_bins": grids.PHI_BINS,
            "pilot_paths": compute.PILOT_PATHS, "aim_se": AIM_SE,
            "aim_albedo_se": compute.AIM_ALBEDO_SE,
            "max_samples": compute.MAX_SAMPLES, "quick_max_samples": compute.QUICK_MAX_SAMPLES,
            "model_points": compute.MODEL_POINTS,
            "quick_model_points": compute.QUICK_MODEL_POINTS, "bin_nodes": compute.BIN_NODES}


def command_of(models, *, samples, seed, quick, values, theta_i, write_package_data) -> str:
    """The ``fitlab atlas`` command line of these arguments (no output folder: the files are
    the same wherever they go)."""
    parts = ["fitlab atlas"]
    for m in models or ():
        parts.append(f"--model '{m}'")
    for k, v in (values or {}).items():
        parts.append(f"--values {k}={','.join(f'{x:g}' for x in v)}")
    if theta_i is not None:
        parts.append(f"--theta-i {','.join(f'{t:g}' for t in theta_i)}")
    if samples is not None:
        parts.append(f"--samples {samples}")
    if seed:
        parts.append(f"--seed {seed}")
    if quick:
        parts.append("--quick")
    if write_package_data:
        parts.append("--write-package-data")
    return " ".join(parts)


def _previous(path: Path):
    """The atlas record at ``path`` if there is a valid one, else None."""
    from fitlab.errors import InputFileError

    if not path.exists():
        return None
    try:
        return region.load(path)
    except InputFileError:
        return None


def atlas(models=None, *, out: str | Path = DEFAULT_OUT, samples: int | None = None,
          seed: int = 0, quick: bool = False, write_package_data: bool = False,
          values: dict | None = None, theta_i=None, progress: bool = True) -> AtlasResult:
    """Make the validation atlas of ``models`` (registry names of :data:`fitlab.atlas.grids.GRIDS`;
    default all) into the folder ``out``: ``atlas.json`` (the record; entries of earlier runs
    there that this one does not redo are kept), ``README.md`` (the page) and each model's maps
    (PNG and SVG). ``samples``: paths per incidence at every point (default: a pilot run sets
    them, fitlab/atlas/compute.py); ``seed``: the simulator's seed; ``quick``: every third
    grid value, at most 100,000 paths, fewer model points (a smoke run); ``values``: {axis name:
    values} to replace one model's axis; ``theta_i``: other incidences;
    ``write_package_data``: also merge the entries into ``fitlab/models/data/layered_atlas.json``
    (the grids as shipped only, and ``out`` the source tree's ``reports/layered_atlas``, the
    page its links name). ValueError saying what to do for bad arguments."""
    from fitlab.fitting import progress as prog
    from fitlab.io.atomic import atomic_open, atomic_write_text
    from fitlab.report import atlas as drawn

    t_start = time.perf_counter()
    if samples is not None and samples < 2:
        raise ValueError("--samples must be at least 2 paths per incidence")
    specs = specs_for(models, quick=quick, values=values, theta_i=theta_i)
    out = Path(out)
    if write_package_data:
        if values or theta_i is not None:
            raise ValueError("--write-package-data keeps the grids as shipped: leave out "
                             "--values and --theta-i")
        home = SOURCE_ROOT / DEFAULT_OUT
        if out.resolve() != home.resolve():
            raise ValueError(f"--write-package-data writes the page its links name, "
                             f"{region.PAGE}: run it from fitlab's source tree's root or give "
                             f"--out {home}")
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: is a file, not a folder")
    say = prog.line if progress else (lambda msg: None)
    estimate = estimate_s(specs, samples=samples, quick=quick)
    total = sum(len(s.axes[0].values) * len(s.axes[1].values) for s in specs)
    say(f"atlas: {len(specs)} model(s), {total} grid points; estimated {estimate / 60:.1f} min "
        "on a 2-core CPU (the grids' measured costs; the bar's estimate follows the run)")
    command = command_of(models, samples=samples, seed=seed, quick=quick, values=values,
                         theta_i=theta_i, write_package_data=write_package_data)
    from fitlab.simulate import engine

    backend = engine.load("auto").backend
    bar = prog.bar(progress, total, "atlas", "point")
    entries, seconds = [], {}
    try:
        for spec in specs:
            t0 = time.perf_counter()
            say(f"atlas: {spec.model}: {len(spec.axes[0].values)} x "
                f"{len(spec.axes[1].values)} points")

            if bar is not None:
                bar.set_description(f"atlas: {spec.model}")

            def on_point(k, n, s):
                if bar is not None:
                    bar.update(1)

            entry = compute.compute_entry(spec, samples=samples, seed=seed, quick=quick,
                                          on_point=on_point)
            provenance = {"command": command, "seed": int(seed), "quick": bool(quick),
                          "samples": "pilot" if samples is None else int(samples),
                          "simulator_backend": backend}
            entries.append(region.finish(entry, provenance))
            seconds[spec.model] = time.perf_counter() - t0
            say(f"atlas: {spec.model}: within {region.THRESHOLD:.0%}: "
                f"{entries[-1]['region']} ({seconds[spec.model]:.0f} s)")
    finally:
        if bar is not None:
            bar.close()
    new = region.record(entries, method())
    out.mkdir(parents=True, exist_ok=True)
    rec = region.merged(_previous(out / "atlas.json"), new)
    files = {}
    for e in entries:
        files.update(drawn.figures(e))
    full_estimate = estimate_s([grids.GRIDS[n] for n in grids.GRIDS]) / 60
    files["atlas.json"] = region.to_json(rec).encode("utf-8")
    files["README.md"] = drawn.page(rec, full_estimate).encode("utf-8")
    for name in sorted(files, key=lambda n: (n == "README.md", n)):  # the page last
        with atomic_open(out / name, "wb") as fh:
            fh.write(files[name])
    package = None
    if write_package_data:
        package = region.DATA_PATH
        pkg = region.merged(_previous(package), new)
        atomic_write_text(package, region.to_json(pkg))
        region._CACHE.clear()
    wall = time.perf_counter() - t_start
    say(f"atlas: wrote {out / 'README.md'}, atlas.json and {len(entries)} map(s)"
        + (f"; package data {package.name}" if package else "") + f" in {wall / 60:.1f} min ("
        + ", ".join(f"{k} {v:.0f} s" for k, v in seconds.items()) + ")")
    return AtlasResult(rec, out, tuple(sorted(files)), package, wall)


__all__ = ["AtlasResult", "DEFAULT_OUT", "atlas", "command_of", "estimate_s", "specs_for"]
