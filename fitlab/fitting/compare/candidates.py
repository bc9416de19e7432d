"""The candidates of a comparison: :class:`Candidate`, the command line's ``--model '...'``
(:func:`parse_candidate`), and :func:`resolve_candidates`, which checks them all before anything
is fitted."""

from __future__ import annotations

import shlex
from typing import NamedTuple

from fitlab.errors import FitlabError

CANDIDATE_FLAGS = ("--fix", "--option", "--free", "--start", "--label")


# --------------------------------------------------------------------------------------------
# Candidates
# --------------------------------------------------------------------------------------------


class Candidate(NamedTuple):
    """One model to compare: a registry name (sums and layered models too), parameters held
    fixed, model options, parameters to fit that the data file would fix, and the label of its
    row in the table (default: the model's name, or its whole spec where two candidates share a
    model)."""

    model: str
    fix: dict | None = None
    options: dict | None = None
    free: tuple = ()
    label: str | None = None
    start: dict | None = None


def parse_candidate(text: str) -> Candidate:
    """A candidate written as on the command line: ``NAME [--fix P=V]... [--option O=V]...
    [--free P]... [--start P=V]... [--label TEXT]`` (shell quoting), e.g. ``"coated(lambertian,specular=lobe)
    --option interreflection=closed_form --fix coat_eta=1.5"``."""
    from fitlab.assignments import parse_assignments

    where = f"--model {text!r}"
    try:
        tokens = shlex.split(text)
    except ValueError as exc:
        raise FitlabError(f"{where}: {exc}; quote the candidate as one argument, e.g. "
                          "--model 'coated(lambertian) --fix coat_eta=1.5'") from None
    k = next((i for i, t in enumerate(tokens) if t.startswith("--")), len(tokens))
    name = " ".join(tokens[:k])
    if not name:
        raise FitlabError(f"{where}: give a model name first (see `fitlab models`), then its "
                          f"{', '.join(CANDIDATE_FLAGS)}")
    got = {flag: [] for flag in CANDIDATE_FLAGS}
    rest = tokens[k:]
    i = 0
    while i < len(rest):
        flag, eq, value = rest[i].partition("=")
        if flag not in got:
            raise FitlabError(f"{where}: unexpected {rest[i]!r}; after the model name a "
                              f"candidate takes {', '.join(CANDIDATE_FLAGS)}")
        if not eq:
            if i + 1 >= len(rest) or rest[i + 1].startswith("--"):
                raise FitlabError(f"{where}: {flag} needs a value")
            value, i = rest[i + 1], i + 2
        else:
            i += 1
        got[flag].append(value)
    if len(got["--label"]) > 1:
        raise FitlabError(f"{where}: --label is given twice")
    fix = {}
    for pname, v in parse_assignments(got["--fix"], "fix").items():
        try:
            fix[pname] = float(v)
        except ValueError:
            raise FitlabError(f"{where}: --fix {pname}={v!r}: the value must be a number") \
                from None
    return Candidate(name, fix, parse_assignments(got["--option"], "option"),
                     tuple(got["--free"]), got["--label"][0] if got["--label"] else None,
                     parse_assignments(got["--start"], "start") or None)


class Resolved(NamedTuple):
    """A candidate checked: its label, its spec (as the command line writes its own settings)
    and its :class:`fitlab.fitting.request.FitRequest` (the comparison's settings with the
    candidate's model, fixed values, options, freed parameters and start)."""

    label: str
    spec: str
    request: object  # fitlab.fitting.request.FitRequest

    @property
    def model(self):
        return self.request.model

    @property
    def fix(self) -> dict:
        return dict(self.request.fix)

    @property
    def options(self) -> dict:
        return dict(self.request.options)

    @property
    def free(self) -> tuple:
        return self.request.free

    @property
    def start(self) -> dict:
        return dict(self.request.start)


def _spec(name, fix, options, free, start) -> str:
    parts = [name] + [f"--option {k}={v}" for k, v in options.items()]
    parts += [f"--fix {k}={v:g}" for k, v in fix.items()] + [f"--free {p}" for p in free]
    parts += [f"--start {k}={v:g}" for k, v in start.items()]
    return " ".join(parts)


def resolve_candidates(models, fix=None, options=None, free=(), settings=None) -> list[Resolved]:
    """Every candidate checked before anything is fitted (model names, options, parameters and
    their values); ``fix``, ``options`` and ``free`` apply to each candidate that has that
    parameter or option (a candidate's own settings win), and each must apply to one at least.
    ``settings``: the comparison's shared FitRequest settings (loss, subset, steps, seed, …),
    checked once; each candidate's request is a variant of them (default: FitRequest's
    defaults)."""
    from fitlab.models import get_model
    from fitlab.fitting.request import FitRequest

    fix, options, free = dict(fix or {}), dict(options or {}), tuple(free or ())
    if isinstance(models, (str, Candidate)):
        models = [models]
    cands = []
    for item in models:
        if isinstance(item, str):
            item = parse_candidate(item) if "--" in item else Candidate(item)
        elif isinstance(item, dict):
            item = Candidate(**item)
        elif not isinstance(item, Candidate):
            raise FitlabError(f"models: {item!r} is not a model name or a Candidate")
        cands.append(item)
    if len(cands) < 2:
        raise FitlabError(f"give at least two models to compare (got {len(cands)}): repeat "
                          "--model, e.g. --model lambertian+rough_conductor --model "
                          "'weidlich_wilkie(lambertian)'")
    mdls = []
    for c in cands:
        try:
            mdls.append(get_model(c.model))
        except ValueError as exc:
            raise FitlabError(f"--model {c.model!r}: {exc} (see `fitlab models`)") from None
    base = FitRequest(mdls[0], spelling="cli", **(settings or {}))
    used_fix, used_opt, used_free = set(), set(), set()
    out = []
    for c, mdl in zip(cands, mdls):
        where = f"--model {c.model!r}"
        names = mdl.parameter_names
        opt_names = {o.name for o in mdl.options}
        glob_fix = {k: v for k, v in fix.items() if k in names}
        glob_opt = {k: v for k, v in options.items() if k in opt_names}
        glob_free = tuple(p for p in free if p in names)
        used_fix |= set(glob_fix)
        used_opt |= set(glob_opt)
        used_free |= set(glob_free)
        own_fix, own_opt, own_free = dict(c.fix or {}), dict(c.options or {}), tuple(c.free or ())
        own = {"model": mdl, "fix": {**glob_fix, **own_fix}, "options": {**glob_opt, **own_opt},
               "free": own_free + glob_free, "start": c.start or {}}
        try:
            request = base.replace(**own)
        except FitlabError as exc:
            raise FitlabError(f"{where}: {exc}") from None
        spec = _spec(mdl.name, {k: request.fix[k] for k in own_fix}, own_opt, own_free,
                     request.start)
        out.append(Resolved(c.label, spec, request))
    for what, given, used in (("--fix", fix, used_fix), ("--option", options, used_opt),
                              ("--free", free, used_free)):
        unused = [k for k in given if k not in used]
        if unused:
            raise FitlabError(f"{what} {', '.join(unused)}: no candidate model has "
                              f"{'an option' if what == '--option' else 'a parameter'} of that "
                              "name; check the spelling, or give it to one candidate inside its "
                              "--model '...'")
    counts = {}
    for r in out:
        counts[r.model.name] = counts.get(r.model.name, 0) + 1
    out = [r._replace(label=r.label or (r.model.name if counts[r.model.name] == 1 else r.spec))
           for r in out]
    labels = [r.label for r in out]
    dup = sorted({x for x in labels if labels.count(x) > 1})
    if dup:
        raise FitlabError(f"--model: two candidates are both {dup[0]!r}; give each a different "
                          "setting or a --label")
    return out
