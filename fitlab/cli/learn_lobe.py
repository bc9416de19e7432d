"""fitlab learn-lobe: SpongeCake's parameter-mapping network (§5), dataset and training in one
resumable command (fitlab.learn.network)."""

from __future__ import annotations

import sys
import time

from fitlab.cli.common import add_quiet
from fitlab.errors import FitlabError


def add_parser(sub):
    from fitlab.learn.network import GRID, LAYERS, SAMPLES, STACKS, THETA_I

    p = sub.add_parser(
        "learn-lobe", help="train SpongeCake's multiple-scattering network on simulated stacks",
        description="Make the training stacks that DIR lacks (one simulated one-layer SGGX "
        f"stack per file (or two-layer, --layers 2), random parameters from the seed and its index; {len(THETA_I)} "
        f"incidences, a {GRID[0]}x{GRID[1]} grid per side), then train the parameter-mapping "
        "network of SpongeCake section 5 (3 hidden layers of 128; equinox + optax: pip install "
        "'fitlab[learn]') on 90% of them and write its weights and their provenance (dataset, "
        "seeds, held-out error). Interrupted, it resumes: rerun the same command. Models use "
        "the weights as spongecake(K,multiple=learned) (data_formats/layered_models.md).",
        epilog="examples: fitlab learn-lobe --dir lobe_data --out ms.npz (writes ms.npz and "
        "ms.json; with the defaults and seed 0 these are the shipped weights, "
        "fitlab/models/data/spongecake_ms_1layer.npz; about 11 min here); fitlab learn-lobe "
        "--layers 2 --jobs 2 --dir lobe_data_2 --out ms2.npz (the shipped two-layer weights, "
        "spongecake_ms_2layer.npz; 12,000 stacks, about 40 min here)")
    p.add_argument("--dir", required=True, metavar="DIR", help="the training stacks' folder")
    p.add_argument("--layers", type=int, choices=LAYERS, default=1,
                   help="flake layers per stack: one network per number of layers, as in the "
                   "paper (default 1)")
    p.add_argument("--stacks", type=int, default=None, help="stacks in the dataset "
                   f"(default {STACKS[1]:,} for one layer and {STACKS[2]:,} for two, the "
                   "paper's and the shipped weights'; every tenth is held out)")
    p.add_argument("--jobs", type=int, default=1, help="processes that simulate the stacks "
                   "(default 1; the files do not depend on it)")
    p.add_argument("--samples", type=int, default=SAMPLES,
                   help=f"paths per incidence of each stack (default {SAMPLES})")
    p.add_argument("--steps", type=int, default=8000,
                   help="training steps (default 8000, the shipped weights')")
    p.add_argument("--seed", type=int, default=0, help="seed of the stacks and the training")
    p.add_argument("--out", required=True, metavar="WEIGHTS.npz",
                   help="the weights (and WEIGHTS.json, their provenance)")
    add_quiet(p)
    return p


def run(args):
    if args.stacks is not None and args.stacks < 10:
        raise FitlabError("--stacks must be at least 10 (every tenth is held out)")
    if args.samples < 2 or args.steps < 1 or args.jobs < 1:
        raise FitlabError("--samples must be at least 2, --steps and --jobs at least 1")
    if not str(args.out).endswith(".npz"):
        raise FitlabError(f"--out {args.out}: give a .npz file name (WEIGHTS.json is written "
                          "beside it)")
    try:
        import equinox  # noqa: F401
        import optax  # noqa: F401
    except ImportError:
        raise FitlabError("training needs equinox and optax: pip install 'fitlab[learn]'") \
            from None
    from fitlab.learn.network import learn

    t0 = {}

    def progress(stage, k, n, done_here, loss=None):
        """``done_here``: the units this run did (stacks simulated, steps): the estimate
        counts only those, so a resumed dataset's existing stacks do not skew it."""
        if args.quiet:
            return
        now = time.perf_counter()
        start = t0.setdefault(stage, now)
        el = now - start
        eta = f"about {el / done_here * (n - k):.0f} s left" if done_here else "estimating"
        extra = f", loss {loss:.4f}" if loss is not None else ""
        print(f"\r{stage}: {k}/{n} ({el:.0f} s, {eta}{extra})   ",
              end="" if k < n else "\n", file=sys.stderr, flush=True)

    try:
        prov = learn(args.dir, args.out, stacks=args.stacks, samples=args.samples,
                     steps=args.steps, seed=args.seed, progress=progress, layers=args.layers,
                     jobs=args.jobs)
    except ValueError as exc:
        raise FitlabError(str(exc)) from None
    if not args.quiet:
        e = prov["errors"]
        print(f"{prov['dataset']['stacks']} stacks ({prov['dataset']['skipped_empty_cells']} "
              f"skipped for empty cells), {e['held_out_stacks']} held out: held-out loss "
              f"{e['held_out_loss']:.3f} (training {e['train_loss']:.3f}), held-out RMS relative "
              f"error median {e['held_out_rms_median']:.3f}; wrote {args.out} and its .json",
              file=sys.stderr)
    return 0
