"""Leave-one-incidence-out cross-validation of a joint fit (``fitlab fit --share``).

`fitlab compare` ranks candidates channel by channel and has no ``--share``: it cannot score a
model whose parameters are shared across channels. This script applies compare's
cross-validation rules (data_formats/compare.md) to one joint fit through the Python API: for
each incidence direction (θi, φi) among the fitted rows, ``fitlab.fit`` (same model, fixed
values, options, shared parameters, starts and seed; no bootstrap) is repeated without that
incidence's rows in every channel, and the refitted model predicts them. Per channel it prints
the RMS relative error of the fit to every row and of the held-out rows, per incidence and
pooled, over each incidence's rows ≥ 1% of that incidence's maximum in the channel (compare's
rule; `fitlab compare`'s figures for independent fits are comparable with these).

    .venv/bin/python benchmarks/joint_cv.py DATA --model lambertian+rough_conductor \\
        --share alpha [--fix P=V] [--option O=V] [--fit-subset EXPR] [--starts 8] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

FLOOR = 0.01


def rms(x):
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def counted_errors(pred, m, rows):
    """(model − data)/data of ``rows`` whose |value| is ≥ 1% of their incidence's maximum in
    their channel, grouped by (channel, incidence)."""
    keys = np.stack([m.theta_i, np.mod(m.phi_i, 360.0)], axis=1)
    out = {}
    for c in np.unique(m.channel[rows]):
        for ti, pi in np.unique(keys[rows & (m.channel == c)], axis=0):
            s = rows & (m.channel == c) & (keys[:, 0] == ti) & (keys[:, 1] == pi)
            v = m.value[s]
            keep = np.abs(v) >= FLOOR * np.max(np.abs(v))
            out[(int(c), float(ti), float(pi))] = (pred[s][keep] - v[keep]) / v[keep]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data")
    ap.add_argument("--model", required=True)
    ap.add_argument("--share", required=True, help="comma-separated shared parameters")
    ap.add_argument("--fix", action="append", default=[], metavar="P=V")
    ap.add_argument("--option", action="append", default=[], metavar="O=V")
    ap.add_argument("--fit-subset", default=None)
    ap.add_argument("--starts", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    import fitlab
    from fitlab.fitting.subset import subset_mask

    m = fitlab.read(args.data)
    fix = {k: float(v) for k, v in (a.split("=", 1) for a in args.fix)}
    options = dict(a.split("=", 1) for a in args.option)
    share = [s for s in args.share.split(",") if s]
    rows = (subset_mask(args.fit_subset, m) if args.fit_subset
            else np.ones(m.n, dtype=bool))
    keys = np.stack([m.theta_i, np.mod(m.phi_i, 360.0)], axis=1)
    incs = [tuple(k) for k in np.unique(keys[rows], axis=0)]
    common = dict(fix=fix, options=options, share=share, starts=args.starts, seed=args.seed,
                  bootstrap=0)
    t0 = time.perf_counter()
    full = fitlab.fit(m, args.model, subset=rows, **common)
    t_full = time.perf_counter() - t0
    print(f"full fit: {t_full:.0f} s", file=sys.stderr, flush=True)
    in_sample = counted_errors(full.predict_measurement(m), m, rows)
    held = {}
    for ti, pi in incs:
        t1 = time.perf_counter()
        out = rows & (keys[:, 0] == ti) & (keys[:, 1] == pi)
        fold = fitlab.fit(m, args.model, subset=rows & ~out, **common)
        held.update(counted_errors(fold.predict_measurement(m), m, out))
        print(f"fold without θi = {ti:g}°: {time.perf_counter() - t1:.0f} s", file=sys.stderr,
              flush=True)
    print(f"\n{args.model}, --share {','.join(share)}"
          + "".join(f" --fix {k}={v:g}" for k, v in fix.items())
          + "".join(f" --option {k}={v}" for k, v in options.items())
          + (f" --fit-subset {args.fit_subset!r}" if args.fit_subset else "")
          + f"; {len(incs)} folds, {time.perf_counter() - t0:.0f} s in all\n")
    print("| channel | measure | " + " | ".join(f"{ti:g}°" for ti, _ in incs)
          + " | pooled |")
    print("|---|---|" + "---|" * (len(incs) + 1))
    for c, name in enumerate(m.channel_names):
        for label, table in (("in-sample", in_sample), ("held-out (CV)", held)):
            errs = [table.get((c, ti, pi), np.zeros(0)) for ti, pi in incs]
            pooled = np.concatenate(errs)
            print(f"| {name} | {label} | " + " | ".join(f"{rms(e):.3f}" for e in errs)
                  + f" | {rms(pooled):.3f} |")
    params = full.parameters
    print("\nfull fit parameters: " + "; ".join(
        f"{ch}: " + ", ".join(f"{k} {v:.4g}" for k, v in params[ch].items())
        for ch in full.channels))


if __name__ == "__main__":
    main()
