"""fitlab fit: a registry model fitted to a measurement file (least squares with global starts,
optional MCMC), written as a parameter file (and a report)."""

from __future__ import annotations

import sys

from fitlab.assignments import parse_assignments
from fitlab.cli.common import (add_channel, add_format, add_model, add_option, add_quiet,
                               add_read_options, add_verbose, read_kwargs)
from fitlab.errors import FitlabError
from fitlab.fitting.losses import LOSSES
from fitlab.fitting.model_check import MODES as CHECK_MODES
from fitlab.fitting.searches import add_global_search_option
from fitlab.fitting.solvers import add_local_solver_option
from fitlab.fitting.status import Status, channel_statuses


def add_parser(sub):
    p = sub.add_parser(
        "fit", help="fit a model to measurements (least squares, global starts, optional MCMC)",
        description="Fit a registry model to a measurement file (data_formats/measurement_csv.md): "
        "a global scan of the parameter box and multi-start Levenberg-Marquardt (jaxopt, vmapped over the starts), "
        "covariance from the Jacobian, optional posterior sampling with emcee. Writes a parameter "
        "file (data_formats/fit_json.md). Compiled kernels are kept on disk for later runs, in "
        "$FITLAB_CACHE_DIR or else $XDG_CACHE_HOME/fitlab/xla or ~/.cache/fitlab/xla "
        "(FITLAB_NO_CACHE=1: no cache).",
        epilog="example: fitlab fit data_formats/examples/walter_rough_glass.csv --model "
        "rough_dielectric --fit-subset 'theta_i == 0' --mcmc --out fits/walter_rough_glass.json",
    )
    p.add_argument("data", nargs="+", metavar="DATA",
                   help="measurement file (any format fitlab reads); several files, or a "
                   "file with a dataset column (one fit per dataset), are fitted at once by "
                   "batched least squares (fitlab.fit_many): give --out-dir and/or --table")
    add_model(p, help="model name (see `fitlab models`)", required=True)
    add_option(p, help="a model option")
    p.add_argument("--fix", action="append", metavar="NAME=VALUE",
                   help="hold a parameter at a value (e.g. --fix eta=1.51)")
    p.add_argument("--start", action="append", metavar="NAME=VALUE",
                   help="one more Levenberg-Marquardt start at these values (the model's "
                   "defaults elsewhere), for a basin the global search may miss (e.g. "
                   "--start kappa1=3000: a thin layer's sharp coat)")
    p.add_argument("--free", action="append", metavar="NAME",
                   help="fit a parameter the data file would fix (eta from # eta_inside/outside)")
    p.add_argument("--loss", choices=list(LOSSES),
                   help="default: chi2 when the data have sigma, else relative")
    p.add_argument("--fit-subset", metavar="EXPR",
                   help="fit only these rows, predict the rest, e.g. 'theta_i == 0', "
                   "'value > 0.01 and theta_o < 80', 'row %% 8 == 0', 'specular_deg > 3' (names: "
                   "theta_i, phi_i, theta_o, phi_o, value, sigma (when given), channel, row, "
                   "specular_deg = angle to the mirror direction, to leave out a smooth coat's "
                   "delta peak; + - * / %%, "
                   "comparisons, and/or/not, abs)")
    add_channel(p, "fit only this channel (default: every channel separately)")
    p.add_argument("--share", action="append", metavar="NAME[,NAME...]",
                   help="a parameter shared by every channel (e.g. --share alpha: one geometry, "
                   "colour per channel); the channels are then fitted jointly, as one problem "
                   "(data_formats/fit_json.md, 'Joint fits')")
    p.add_argument("--mcmc", action="store_true",
                   help="sample the posterior (emcee unless --sampler)")
    from fitlab.fitting.samplers import SAMPLERS

    p.add_argument("--sampler", choices=list(SAMPLERS), default="emcee",
                   help="posterior sampler with --mcmc: "
                   + "; ".join(f"{k}: {v.description}" for k, v in SAMPLERS.items())
                   + " (default emcee; with nuts, --walkers is the number of chains, default 4)")
    p.add_argument("--mcmc-steps", type=int, default=None,
                   help="steps per walker with emcee (default 3000); adaptation steps and draws "
                   "per chain with nuts (default 1000)")
    p.add_argument("--walkers", type=int, help="number of walkers (default max(32, 4 x dim))")
    p.add_argument("--starts", type=int, default=8,
                   help="low-discrepancy Levenberg-Marquardt starts besides the global search "
                   "(default 8)")
    add_global_search_option(p)
    add_local_solver_option(p)
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice (default 0)")
    p.add_argument("--lm-maxiter", type=int, metavar="N",
                   help="step limit of each Levenberg-Marquardt run (default 200); raise it when "
                   "the fit warns that its run stopped at the limit (solver.stopped = "
                   "max_iterations in the parameter file)")
    p.add_argument("--aperture-order", type=int, metavar="N",
                   help="quadrature order over each row's aperture (data with a detector cone, "
                   "bin or source divergence are fitted by the aperture-averaged model; "
                   "data_formats/measurement_csv.md); default: chosen from the measured "
                   "quadrature error, order 4 doubled until order 2N moves the fit by less "
                   "than 0.1 standard errors")
    p.add_argument("--bootstrap", type=int, metavar="N",
                   help="refits of the block bootstrap over incidence directions, an "
                   "uncertainty that accounts for misfit (parameters.*.bootstrap; default: on "
                   "channels with at least 3 fitted incidences, until each 68%% bound moves by "
                   "less than 5%% of its interval's width over 20 refits, at most 100; skipped "
                   "when least squares ended at a bound or its iteration limit; N: exactly N; "
                   "0: off)")
    p.add_argument("--illuminant", metavar="NAME",
                   help="spectral data (channels that are wavelengths spanning 380-780 nm): the "
                   "CIE illuminant under which the parameter file's colour block reduces each "
                   "colour parameter's spectrum to CIE XYZ and linear sRGB (CIE 1931 2 degree "
                   "observer): a colour-science name, D65 (default), D50, A, E, FL2, ...; "
                   "data_formats/fit_json.md, 'Colour of a spectral fit'")
    p.add_argument("--check-model", choices=CHECK_MODES, default="auto",
                   help="check a layered model against the Monte Carlo simulation of its own "
                   "fitted stack at the fitted directions (at most 4000 rows), with paths for "
                   "a relative standard error of 2%%; prints the model's error there beside "
                   "the fit's and records both (fits[k].model_check): auto (default) runs it "
                   "when its cost, estimated from a pilot run, is at most max(20%% of the "
                   "fit's time, 10 s) and says why it skipped it otherwise; on: always; off: "
                   "never (data_formats/fit_json.md, 'Model check')")
    p.add_argument("--walter-diagnostics", action="store_true",
                   help="add Walter 2007 section 6.1's empirical D points to the parameter file")
    p.add_argument("--out", metavar="FILE.json", help="parameter file (default: standard output)")
    p.add_argument("--out-dir", metavar="DIR",
                   help="several DATA files: one parameter file per file, DIR/NAME.json "
                   "(NAME: the data file's name without its suffix)")
    p.add_argument("--table", metavar="FILE.csv",
                   help="several DATA files: one CSV row per file and channel with every "
                   "parameter and its standard error (data_formats/fit_table_csv.md)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="several DATA files: fit them on N local Dask worker processes "
                   "(Dask.distributed; 1 runs the chunks in this process; resumable: a rerun "
                   "skips the chunks already done); "
                   "writes --out-dir DIR/NAME.json, DIR/table.csv and DIR/index.json")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="several DATA files: send the chunks to a running Dask scheduler "
                   "(tcp://HOST:8786; its workers need fitlab and the same --out-dir path)")
    p.add_argument("--files-per-chunk", type=int, metavar="N",
                   help="with --workers/--scheduler: files per task (default 64)")
    p.add_argument("--chunk", type=int, metavar="N",
                   help="several DATA files: datasets per compiled batched call (default "
                   "1024; memory grows with it)")
    p.add_argument("--chain", metavar="FILE.npz", help="also write the MCMC chain")
    p.add_argument("--timings", action="store_true",
                   help="record the run's wall-clock seconds in the parameter file (timings_s); "
                   "they differ from run to run, so without this the same data, options and "
                   "seed give the same bytes")
    p.add_argument("--report", metavar="DIR",
                   help="then write an HTML report of the fit into DIR (as `fitlab report`; "
                   "needs --out; with --chain it shows posterior bands and MCMC plots)")
    add_quiet(p)
    add_verbose(p)
    add_format(p)
    add_read_options(p)
    return p


#: Outputs of a single fit that a batched fit of several files does not write, and why (the
#: fit settings it does not offer are fitlab.fitting.many.check_batch's).
_SINGLE_ONLY = {"out": "--out (give --out-dir DIR: one file per dataset, or --table)",
                "chain": "--chain (the table and the parameter files hold the posteriors' "
                         "summaries)",
                "report": "--report (run fitlab report on a file of --out-dir)"}


def _run_many(args):
    """fitlab fit DATA DATA ... : fitlab.fit_many, then parameter files and/or a table."""
    from pathlib import Path

    from fitlab.export.paramfile import write_fit
    from fitlab.fitting.api import read
    from fitlab.fitting.many import fit_many, output_name
    from fitlab.io.atomic import atomic_write_text

    used = [flag for name, flag in _SINGLE_ONLY.items()
            if getattr(args, name, None) not in (None, False, [], ())]
    if used:
        raise FitlabError(f"several data files are fitted at once (batched least squares); "
                          f"not with {', '.join(used)}")
    if not (args.out_dir or args.table):
        raise FitlabError("several data files: give --out-dir DIR (a parameter file per "
                          "file) and/or --table FILE.csv (one row per file and channel)")
    from fitlab.fitting.batch import CHUNK
    from fitlab.fitting.many import check_batch

    chunk = CHUNK if args.chunk is None else args.chunk
    request = check_batch(request_of(args, walkers=args.walkers or 4), chunk=chunk)
    ms = [d for path in args.data for d in read(path, args.format, **read_kwargs(args)).datasets()]
    names = [output_name(m) for m in ms]
    if args.out_dir and len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise FitlabError(f"--out-dir: several data files are named {', '.join(dup)}; "
                          "rename them (each gets DIR/NAME.json)")
    result = fit_many(ms, request, chunk=chunk)
    written = 0
    if args.out_dir:
        out = Path(args.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        for i, record in result.records():
            write_fit(out / f"{names[i]}.json", record)
            written += 1
    if args.table:
        atomic_write_text(args.table, result.table(args.table))
    if not args.quiet:
        stopped = sum(f.lm_stopped != Status.CONVERGED for f in result.fits)
        print(f"fitted {len(result.fits)} datasets of {len(args.data)} files in {result.seconds:.2f} s "
              f"({len(result.fits) / result.seconds:.1f} fits/s, {result.groups} structure"
              f"{'s' if result.groups > 1 else ''})"
              + (f"; {stopped} did not converge (see lm_stopped)" if stopped else ""),
              file=sys.stderr)
        if args.out_dir:
            print(f"wrote {written} parameter files to {args.out_dir}", file=sys.stderr)
        if args.table:
            print(f"wrote {args.table}", file=sys.stderr)
    return 0


def _run_distributed(args):
    """fitlab fit DATA ... --workers N | --scheduler ADDRESS: fitlab.fitting.distributed."""
    from fitlab.fitting.distributed import FILES_PER_CHUNK, fit_files

    used = [flag for name, flag in _SINGLE_ONLY.items()
            if getattr(args, name, None) not in (None, False, [], ())]
    if args.table:
        used.append("--table (the table is DIR/table.csv)")
    if used:
        raise FitlabError(f"--workers/--scheduler fit the files in chunks on Dask workers; "
                          f"not with {', '.join(used)}")
    if not args.out_dir:
        raise FitlabError("--workers/--scheduler need --out-dir DIR (the workers write the "
                          "parameter files there)")
    request = request_of(args, walkers=args.walkers or 4)  # fit_files checks it as a batch
    summary = fit_files(args.data, request, args.out_dir, workers=args.workers or 2,
                        scheduler=args.scheduler,
                        files_per_chunk=args.files_per_chunk or FILES_PER_CHUNK,
                        progress=not args.quiet, **read_kwargs(args))
    if not args.quiet:
        print(f"{summary['files']} files in {summary['chunks']} chunks: {summary['fitted']} "
              f"fitted now, {summary['done_before']} done before; wrote {summary['table']} and "
              f"{summary['index']}", file=sys.stderr)
    return 0


def request_of(args, **overrides):
    """The FitRequest of the command line's options (``overrides``: settings a path sets
    itself), checked once before any data are read; messages name the options."""
    from fitlab.fitting.request import FitRequest

    settings = dict(
        fix=parse_assignments(args.fix, "fix"), start=parse_assignments(args.start, "start"),
        free=tuple(args.free or ()), options=parse_assignments(args.option, "option"),
        loss=args.loss, subset=args.fit_subset,
        channels=(args.channel,) if args.channel else None, share=_share_names(args.share),
        mcmc=args.mcmc, mcmc_steps=args.mcmc_steps, walkers=args.walkers,
        sampler=args.sampler, starts=args.starts, seed=args.seed,
        global_search=args.global_search, local_solver=args.local_solver,
        aperture_order=args.aperture_order, bootstrap=args.bootstrap,
        lm_maxiter=args.lm_maxiter, walter_diagnostics=args.walter_diagnostics,
        progress=not args.quiet, illuminant=args.illuminant, check_model=args.check_model)
    return FitRequest(args.model, spelling="cli", **{**settings, **overrides})


def _share_names(items):
    """--share alpha --share n,k -> ("alpha", "n", "k")."""
    return tuple(dict.fromkeys(n.strip() for item in items or () for n in item.split(",")
                               if n.strip()))


def _print_brief(record):
    """The fit in two or three lines per channel (``-v``: :func:`_print_summary`): the free
    parameters, the fit error and the goodness verdict, and what limits trust (the statuses;
    the warnings are counted here, kept whole in the parameter file and the report)."""
    from fitlab.metrics import fit_error_of, fit_error_text

    joint = record.get("joint")
    if joint:
        print(f"joint fit of channels {', '.join(joint['channels'])}: "
              f"{', '.join(joint['shared'])} shared", file=sys.stderr)
    for fit in record["fits"]:
        values = []
        for name, p in fit["parameters"].items():
            if p["fixed"]:
                continue
            text = f"{name} = {p['value']:.6g} ± {p['stderr'] or float('nan'):.2g}"
            post = p.get("posterior")
            if post:
                text += f" (posterior 68% [{post['p16']:.4g}, {post['p84']:.4g}])"
            values.append(text)
        print(f"channel {fit['channel']}: {', '.join(values) or 'every parameter fixed'}",
              file=sys.stderr)
        st = fit["statistics"]
        parts = [fit_error_text(fit_error_of(st))]
        if st.get("chi2_per_dof") is not None:
            parts.append(f"chi2/dof {st['chi2_per_dof']:.3g}")
        g = fit.get("goodness")
        if g:
            parts.append("goodness of fit passes" if g["describes_data"] else
                         f"goodness of fit FAILS ({', '.join(g['failed'])})")
        print("  " + "; ".join(parts), file=sys.stderr)
        if st.get("prediction_error"):
            print(f"  predicted (not fitted): {fit_error_text(st['prediction_error'], 'rows')}",
                  file=sys.stderr)
        _print_model_check(fit)
        trouble = [s.value for s in channel_statuses(fit) if not s.ok]
        n_warn = len(fit.get("warnings", []))
        if trouble or n_warn:
            print(f"  status {', '.join(trouble) or 'converged'}"
                  + (f"; {n_warn} warning{'s' if n_warn > 1 else ''} (-v prints "
                     f"{'them' if n_warn > 1 else 'it'} with advice; kept in the parameter file)"
                     if n_warn else ""), file=sys.stderr)
    _print_colour(record)


def _print_colour(record):
    """A spectral fit's colour block (fitlab.export.spectral_colour) in a line or a few."""
    colour = record.get("colour")
    if not colour:
        return
    if colour["parameters"] is None:
        print(f"colour: {colour['reason']}", file=sys.stderr)
        return
    print(f"colour under {colour['illuminant']} (CIE 1931 2 degree observer), "
          f"{len(colour['channels'])} bands:", file=sys.stderr)
    for name, p in colour["parameters"].items():
        if p["reduction"] == "colour":
            print(f"  {name}: linear sRGB " + ", ".join(f"{x:.4g}" for x in p["linear_srgb"])
                  + "; XYZ " + ", ".join(f"{x:.4g}" for x in p["xyz"]), file=sys.stderr)
        elif p["reduction"] != "one value":
            print(f"  {name}: {p['reduction']} {p['value']:.4g} (bands {p['range'][0]:.4g} to "
                  f"{p['range'][1]:.4g})", file=sys.stderr)


def _print_summary(record):
    """The fit's whole account (``fitlab fit -v``)."""
    from fitlab.metrics import fit_error_of, fit_error_text

    joint = record.get("joint")
    if joint:
        print(f"joint fit of channels {', '.join(joint['channels'])}: "
              f"{', '.join(joint['shared'])} shared; {len(joint['parameters'])} free "
              f"coordinates, {joint['n_fit']} rows", file=sys.stderr)
    for fit in record["fits"]:
        print(f"channel {fit['channel']}:", file=sys.stderr)
        for name, p in fit["parameters"].items():
            if p["fixed"]:
                print(f"  {name:>8} = {p['value']:.6g} (fixed)", file=sys.stderr)
                continue
            line = (f"  {name:>8} = {p['value']:.6g} ± {p['stderr'] or float('nan'):.2g} (LS"
                    + (", shared)" if p.get("shared") else ")"))
            post = p.get("posterior")
            if post:
                line += (f";  posterior median {post['median']:.6g}, 68% "
                         f"[{post['p16']:.6g}, {post['p84']:.6g}]")
            boot = p.get("bootstrap")
            if boot:
                line += (f";  bootstrap ± {boot['std']:.2g}, 68% "
                         f"[{boot['p16']:.6g}, {boot['p84']:.6g}]")
            print(line, file=sys.stderr)
        _print_goodness(fit)
        st = fit["statistics"]
        if st.get("chi2_per_dof") is not None:
            print(f"  chi2/dof = {st['chi2_per_dof']:.3f}", file=sys.stderr)
        fe = fit_error_of(st)
        print(f"  {fit_error_text(fe)}", file=sys.stderr)
        if st.get("prediction_error"):
            print(f"  predicted (not fitted): {fit_error_text(st['prediction_error'], 'rows')}",
                  file=sys.stderr)
        _print_model_check(fit, verbose=True)
        fitted_at = {(r["theta_i"], r["phi_i"]): r["rms_relative_error"]
                     for r in (fe or {}).get("per_incidence", ())}
        ap = fit.get("aperture")
        if ap:
            err = ap["quadrature_error"]
            shift = err.get("max_parameter_shift")
            print(f"  aperture: {ap['rows']} rows averaged over their aperture, quadrature order "
                  f"{ap['order']} ({ap['order_choice']}, {ap['nodes_per_row']} nodes per row); "
                  f"its error (against order {err['reference_order']}): parameters "
                  f"{'n/a' if shift is None else f'{shift:.2g}'} standard errors, rows "
                  f"{err['max_row_error']:.2g} noise at most", file=sys.stderr)
        for row in st["per_incidence"]:
            err = row["rms_relative_error"]
            line = (f"    theta_i = {row['theta_i']:6.2f}  phi_i = {row['phi_i']:6.2f}  "
                    f"{row['role']:>10}  n = {row['n']:4d}  RMS rel. error = "
                    f"{'n/a' if err is None else f'{err:.4f}'}")
            part = fitted_at.get((row["theta_i"], row["phi_i"]))
            if row["role"] == "partly fit" and part is not None:
                line += f" (fitted rows {part:.4f})"
            print(line, file=sys.stderr)
        for w in fit.get("warnings", []):
            print(f"warning: channel {fit['channel']}: {w}", file=sys.stderr)
        for status in channel_statuses(fit):
            if not status.ok:
                print(f"status: channel {fit['channel']}: {status.value}: {status.advice}",
                      file=sys.stderr)
    _print_colour(record)


def _print_model_check(fit, verbose: bool = False):
    """The model check's line (fitlab.fitting.model_check), with ``verbose`` its reading."""
    from fitlab.fitting.model_check import check_line, interpretation

    line = check_line(fit["channel"], fit.get("model_check"))
    if line:
        print("  " + line, file=sys.stderr)
        note = interpretation(fit.get("model_check")) if verbose else None
        if note:
            print("    " + note, file=sys.stderr)


def _p(p):
    return "n/a" if p is None else (f"{p:.2g}" if p >= 1e-300 else "< 1e-300")


def _print_goodness(fit):
    """The goodness checks (fitlab.fitting.goodness) in two or three lines."""
    g = fit.get("goodness")
    if not g:
        return
    out = []
    if g.get("chi2"):
        out.append(f"chi2/dof {g['chi2']['chi2_per_dof']:.3g} (p {_p(g['chi2']['p_value'])})")
    lv = g["incidence_level"]
    stat = lv["statistic"]
    vals = [x[stat] for x in g["per_incidence"] if x.get(stat) is not None]
    if vals:
        what = "chi2/dof" if stat == "chi2_per_dof" else "variance ratio"
        out.append(f"per-incidence {what} {min(vals):.3g}-{max(vals):.3g} "
                   f"(p {_p(lv['min_p_value_sidak'])})")
    rt = g["runs_test"]
    out.append(f"runs {rt['runs']} of {rt['expected_runs']:.0f} expected (p {_p(rt['p_value'])})")
    pp = g.get("posterior_predictive")
    if pp:
        out.append(f"posterior predictive p {_p(pp['worst_incidence']['p_value'])} (worst "
                   f"incidence), {_p(pp['chi2']['p_value'])} (chi2)")
    verdict = ("passes" if g["describes_data"] else
               "FAILS: the model does not describe the data (" + ", ".join(g["failed"]) + ")")
    print(f"  goodness of fit {verdict}; checks at p < {g['p_fail']:g}:", file=sys.stderr)
    print("    " + "; ".join(out), file=sys.stderr)
    boot = fit.get("bootstrap")
    if boot and boot.get("replicates"):
        print(f"  bootstrap: {boot['replicates']} refits over {boot['blocks']} incidences"
              + (f"; {boot['stop_reason']}" if boot.get("stop_reason") else "")
              + (f" ({boot['note']})" if boot.get("note") else ""), file=sys.stderr)


def _print_timings(timings):
    names = {"read": "read", "least_squares": "least squares", "mcmc": "MCMC",
             "bootstrap": "bootstrap", "model_check": "model check", "total": "total"}
    print("time: " + ", ".join(f"{names[k]} {v:.2f} s" for k, v in timings.items()),
          file=sys.stderr)


def run(args):
    import time

    from fitlab.fitting.cache import enable_compilation_cache

    enable_compilation_cache()  # before any computation; FITLAB_NO_CACHE=1 turns it off
    from fitlab.fitting.api import fit, read
    from fitlab.fitting.result import thaw

    t0 = time.perf_counter()
    if args.workers or args.scheduler:
        return _run_distributed(args)
    if len(args.data) > 1 or args.out_dir or args.table:
        return _run_many(args)
    args.data = args.data[0]
    if args.chain and not args.mcmc:
        raise FitlabError("--chain needs --mcmc: there is no chain to write")
    if args.report and not args.out:
        raise FitlabError("--report needs --out FILE.json: the report is built from the "
                          "parameter file")
    request = request_of(args)
    m = read(args.data, args.format, **read_kwargs(args))
    t_read = time.perf_counter() - t0
    from fitlab.fitting.progress import brief

    with brief(not args.verbose):  # progress: one transient status line unless -v
        result = fit(m, request)
    summary = _print_summary if args.verbose else _print_brief
    for note in result.notes:
        if not args.quiet:
            print(f"note: {note}", file=sys.stderr)
    timings = {"read": t_read, **result.seconds, "total": time.perf_counter() - t0}
    if args.timings:
        result = result.with_record({**thaw(result.record), "timings_s": timings})
    if args.out:
        result = result.save(args.out, chain=args.chain)
        if not args.quiet:
            summary(thaw(result.record))
            if args.verbose:
                _print_timings(timings)
            print(f"wrote {args.out}" + (f" and {args.chain}" if args.chain else "")
                  + ("" if args.verbose else f" ({timings['total']:.1f} s)"), file=sys.stderr)
        if args.report:
            from fitlab.report.api import write_report

            summary = write_report(result, args.report, data=args.data, chain=args.chain,
                                   progress=not args.quiet)
            if not args.quiet:
                print(f"wrote the report {summary['index']}", file=sys.stderr)
    else:
        if args.chain:
            from fitlab.export.paramfile import chain_bytes
            from fitlab.io.atomic import atomic_open

            with atomic_open(args.chain, "wb") as fh:
                fh.write(chain_bytes(dict(result.chains)))
        if not args.quiet:
            summary(thaw(result.record))
            if args.verbose:
                _print_timings(timings)
        print(result.to_json(), end="")
    return 0
