"""Examples that run (issue 34, item 8): every fenced code block of README.md, data_formats/*.md
and fits/README.md is handled by kind, and a block this module cannot classify fails
``test_block_is_classified`` (a new block is made runnable, or classified in a table below).

- ``python`` blocks run verbatim (``exec``, with the document's line numbers in tracebacks) in a
  temporary working folder holding copies of ``data_formats/`` and ``fits/`` at their relative
  paths. A block that uses names it does not define continues the python block before it in the
  same file and runs in that block's namespace.
- Command blocks (``bash``, and plain blocks of ``fitlab ...`` lines): every ``fitlab`` line
  (``\\`` continuations joined) is checked against ``fitlab.cli.build_parser()``: a usage synopsis
  (``[...]``, ``|``, ``...``) by its subcommand, the options it names (a compare candidate's
  quoted options against the candidate flags) and the choices it lists; any other line is
  parsed whole. Lines without placeholders, and lines whose placeholders PLACEHOLDERS replaces by
  bundled files, then run in-process through ``fitlab.cli.main`` in the working folder and must
  exit 0, unless NOT_RUN says why not (another test runs it, it needs data or services that are
  not bundled, or it takes minutes). Shell lines that are not fitlab are skipped for the reason
  in SHELL_LINES (``mkdir -p DIR`` is done).
- Data blocks are read with fitlab's own reader (DATA_BLOCKS: a scene through load_scene, a
  sweep through load_sweep and compared with the example file it shows, a CSV through
  fitlab.read; the values of values_csv.md are recomputed by the model); the others say why not.

After each run the copied inputs are unchanged, the repository's ``git status --porcelain`` is
unchanged, and for README.md every new file is one the repository ignores (``out/``): nothing a
user runs from the README dirties the checkout. Costly runs are marked slow; a command whose
bytes another test checks is not run again here (NOT_RUN)."""

from __future__ import annotations

import ast
import builtins
import contextlib
import glob
import hashlib
import os
import re
import shlex
import shutil
import subprocess
from functools import lru_cache
from pathlib import Path
from typing import NamedTuple

import pytest

ROOT = Path(__file__).resolve().parents[2]
GIT = "/usr/bin/git"
DOCS = ("README.md", *sorted(p.relative_to(ROOT).as_posix()
                             for p in (ROOT / "data_formats").glob("*.md")), "fits/README.md")
#: What a working folder holds (copies): the bundled inputs the documents name.
INPUT_FOLDERS = ("data_formats", "fits")
#: Documents whose runs must write only files the repository ignores.
CLEAN_CHECKOUT_DOCS = ("README.md",)

# --------------------------------------------------------------------------------------------
# The tables: how a block or a line that is not run verbatim is handled
# --------------------------------------------------------------------------------------------

#: Placeholders of command lines (whole tokens) and the bundled files or values that replace
#: them (outputs go under the ignored out/); EVERY_COMMAND runs the line once per subcommand.
PLACEHOLDERS = {
    "FILE": "data_formats/examples/zemax_brown_vinyl.bsdf",
    "IN": "data_formats/examples/zemax_brown_vinyl.bsdf",
    "OUT.csv": "out/vinyl.csv",
    "FIT.json": "fits/walter_rough_glass.json",
    "OUT.bsdf": "out/glass.bsdf",
    "OUT.binary": "out/glass.binary",
    "OUT.dat": "out/glass.dat",
    "DATA": "data_formats/examples/walter_rough_glass.csv",
    "NAME": "rough_dielectric",
    "COMMAND": "EVERY_COMMAND",  # fitlab.cli.COMMANDS, one run each
}
#: Words that mark a placeholder in a command line (a token or a part of one between = , . / :).
PLACEHOLDER_WORDS = frozenset(
    "A ADDRESS AXIS B C CHAIN COMMAND DATA DATA_DIR DIR EXPR F FILE FIT FITS HOST IN KIND LAYERS "
    "LOBE MODEL MS N NAME O OUT P PAIRS S SCENE SIM SWEEP T TEXT V VALUE VALUES WEIGHTS".split())

#: Lines (after `fitlab`, whitespace collapsed) that are checked against the parser but not run.
NOT_RUN = {
    "fit DATA --model NAME --mcmc --sampler nuts":
        "tests/fitting/test_nuts.py::test_cli_sampler_nuts_writes_it_in_the_file runs it",
    "fit data/*.csv --model rough_dielectric --scheduler tcp://HOST:8786 --out-dir /shared/fits":
        "needs a running Dask scheduler; tests/fitting/test_distributed.py runs a local cluster",
    "simulate --sweep data_formats/examples/sweeps/rough_glass_alpha.toml --out-dir out/sweep/":
        "tests/simulate/test_sweep.py::test_sweep_then_batched_fit_recovers_each_point runs "
        "this pipeline and checks each alpha (100 s: two Dask workers)",
    "fit out/sweep/point_*.csv --model rough_dielectric --fix eta=1.5 --out-dir out/sweep-fits/":
        "the second half of the sweep pipeline (test_sweep.py, above)",
    "compare data_formats/examples/walter_rough_glass.csv --model rough_dielectric --model "
    "'rough_dielectric --option distribution=beckmann --label beckmann' --mcmc-steps 2000 "
    "--starts 2 --no-report --no-fits --out data_formats/examples/compare/":
        "tests/fitting/test_compare.py::test_example_reproduced_by_its_command reruns it and "
        "compares the files",
    "fit DATA --model 'coated(lambertian+rough_conductor,specular=lobe)' --fix coat_eta=1.5 "
    "--fix coat_tau=0 --fix n=1 --share coat_alpha,alpha":
        "a joint RGB fit of a layered model (minutes); tests/fitting/test_share.py fits shared "
        "parameters",
    "info scan.txt": "no pgII scan is bundled (licence unknown: ../shared/data only); "
                     "tests/io/test_io_pgii.py",
    "convert scan.txt scan.csv": "no pgII scan is bundled (tests/io/test_io_pgii.py)",
    "fit scan.txt --model rough_conductor --fix n=1.2 --fix k=2.4":
        "no pgII scan is bundled (tests/io/test_io_pgii.py)",
    "fit data_formats/examples/zemax_brown_vinyl.bsdf --model lambertian+rough_conductor "
    "--out vinyl.json": "the fit is 36 s with its 100-refit bootstrap; the next line runs on "
                        "the committed fit of the same model instead (NEEDS)",
    "learn-lobe --dir lobe_data --out spongecake_ms_1layer.npz":
        "4000 simulated stacks and 8000 training steps (hours); "
        "tests/models/test_spongecake_learned.py trains on a few",
    "learn-lobe --layers 2 --jobs 2 --dir lobe_data_2 --out spongecake_ms_2layer.npz":
        "hours, as above",
    "export fits/brown_vinyl_lambert_ggx_conductor.json --out out/vinyl.gltf --check":
        "the glTF conversion fit of this fit takes 30-50 s; tests/export/test_gltf_browser.py::"
        "test_fitted_export_renders_as_fitlab_predicts runs `export --check` (three.js in "
        "Chromium) on a fitted conversion of a conductor",
    "lut dfg --size 64 --out dfg.exr":
        "19-35 s of quadrature; tests/lut/test_lut.py::test_dfg_reproduces_schlick_conductor_albedo",
    "lut albedo_conductor --dtype float --out E_ggx.exr":
        "28 s of quadrature at 2 cores; tests/lut/test_lut.py bakes the albedo kinds small",
    "lut albedo_dielectric --size 32x32x16 --out E_glass.exr":
        "minutes of quadrature; tests/lut/test_lut.py bakes the albedo kinds small",
}
#: Documents whose commands are checked against the parser, none run.
CHECK_ONLY_DOCS = {
    "fits/README.md": "the reference fits' commands: minutes each, several read ../shared/data "
                      "(not bundled); the README's main fit runs in tests/project/test_determinism.py",
}
#: A line that reads another line's output: (document, consumer) -> producer (commands after
#: `fitlab`, whitespace collapsed, or "python:<first line>" of a python block, or a mkdir line).
#: Where the producer is in NOT_RUN, the value is a command run instead.
NEEDS = {
    ("README.md", "python:import mitsuba as mi"):
        "export fits/brown_vinyl_weidlich_wilkie_lambert.json --to mitsuba-plugin --out "
        "out/vinyl.xml --preview",
    ("data_formats/zemax_bsdf.md",
     "convert vinyl.json vinyl_fit.bsdf --grid data_formats/examples/zemax_brown_vinyl.bsdf"):
        "copy fits/brown_vinyl_lambert_ggx_conductor.json vinyl.json",
    ("data_formats/lut_exr.md", "info glass_brdf.exr"):
        "lut model --from-fit fits/walter_rough_glass.json --out glass_brdf.exr",
}
#: Shell lines that are not fitlab commands: (pattern, reason). `mkdir -p DIR` is run.
SHELL_LINES = (
    (r"python3 -m venv \.venv && \.venv/bin/pip install", "set-up: a fresh virtual environment "
     "(.ci/run installs and runs the test command; the fit of quick start 1 is "
     "tests/project/test_determinism.py::test_readme_main_command_is_byte_identical)"),
    (r"python -m pytest", "the test commands: .ci/run runs the suite"),
    (r"dask (scheduler|worker) ", "starts a Dask cluster (tests/fitting/test_distributed.py)"),
    (r"mitsuba ", "Mitsuba's own renderer, not fitlab (tests/export/ load the exported scenes)"),
    (r"(\.venv/bin/)?python benchmarks/", "a benchmark, run on demand (benchmarks/README.md)"),
    (r"[A-Z]+=", "a shell variable of the commands below"),
)
#: Blocks that are neither python nor commands, by (document, start of the first line): a
#: reader of fitlab's, or why none runs.
DATA_BLOCKS = {
    ("README.md", "fitlab/          the package"): "skip: the repository's layout, not code",
    ("data_formats/stack.md", "STACK/"): "skip: a stack folder's layout (examples/stack/ is "
                                         "the valid one, tests/fitting/test_fit_maps.py reads it)",
    ("data_formats/directions_csv.md", "# fitlab direction file"): "directions",
    ("data_formats/input_validation.md", "fitlab info: error: sample.bsdf"):
        "skip: error messages (each is tested in tests/io/test_hostile_inputs.py)",
    ("data_formats/input_validation.md", "fitlab info: error: scan.csv"):
        "skip: an error message (tests/io/test_format_detection.py)",
    ("data_formats/klems_xml.md", "WindowElement"): "skip: the XML's structure, not a file",
    ("data_formats/openmaterial_xompt.md", "{"):
        "skip: an abridged file (`...`); the whole examples in examples/openmaterial/ are read "
        "by tests/io/test_io_openmaterial.py",
    ("data_formats/lut_exr.md", "float fitlab_fresnel_t0"):
        "skip: an abridged GLSL excerpt (`...`); the whole file "
        "examples/lut_fresnel_copper.glsl is compiled and run by tests/lut/test_lut_glsl.py",
    ("data_formats/measurement_csv.md", "# quantity: bsdf"): "measurement",
    ("data_formats/pgii_text.md", "#pgII [uA]"): "skip: an abridged scan (`...`); no pgII scan "
                                                 "is bundled (licence unknown)",
    ("data_formats/report_html.md", "DIR/index.html"): "skip: a list of files",
    ("data_formats/scene_toml.md", 'format = "fitlab-scene"'): "scene",
    ("data_formats/sweep_toml.md", 'format = "fitlab-sweep"'): "sweep",
    ("data_formats/sweep_toml.md", "sweep_bad_value.toml: point 1"):
        "skip: an error message (tests/simulate/test_sweep.py checks the invalid examples')",
    ("data_formats/tradeoffs_json.md", "{"): "skip: an abridged record (`...`); "
                                             "tests/applications/ check written ones",
    ("data_formats/values_csv.md", "# fitlab eval output"): "values",
    ("data_formats/zemax_bsdf.md", "#Data Generated by Radiant"):
        "skip: an annotated layout; the file itself is examples/zemax_brown_vinyl.bsdf",
}
#: Runs that take more than a second or two (quick tier: the rest).
QUICK_SUBCOMMANDS = ("models", "info")
QUICK_PYTHON = (("data_formats/MITSUBA_MAPPING.md", '{"type": "roughdielectric"'),)

# --------------------------------------------------------------------------------------------
# Reading the documents
# --------------------------------------------------------------------------------------------


class Block(NamedTuple):
    doc: str
    line: int  # of the opening fence
    lang: str
    lines: tuple  # (line number, text) of the body

    @property
    def id(self) -> str:
        return f"{self.doc}:{self.line}"

    @property
    def first(self) -> str:
        return next((t.strip() for _, t in self.lines if t.strip()), "")


def blocks(doc: str) -> list:
    lines = (ROOT / doc).read_text(encoding="utf-8").splitlines()
    found, i = [], 0
    while i < len(lines):
        m = re.match(r"\s*(`{3,}|~{3,})\s*([\w+-]*)", lines[i])
        if m:
            start, fence, body = i + 1, m.group(1), []
            i += 1
            while i < len(lines) and not lines[i].strip().startswith(fence):
                body.append((i + 1, lines[i]))
                i += 1
            found.append(Block(doc, start, m.group(2), tuple(body)))
        i += 1
    return found


def logical_lines(block: Block) -> list:
    """(line number, text) of each command: ``\\`` continuations joined (and a synopsis's
    indented lines of options), comments and blanks left out."""
    out, pending, start = [], "", None
    for n, text in block.lines:
        if not pending and (not text.strip() or text.lstrip().startswith("#")):
            continue
        if not pending and out and text[:1].isspace() and text.lstrip()[:1] in "[-(|":
            out[-1] = (out[-1][0], out[-1][1] + " " + " ".join(text.split()))
            continue
        start = start or n
        if text.rstrip().endswith("\\"):
            pending += text.rstrip()[:-1] + " "
            continue
        out.append((start, " ".join((pending + text).split())))
        pending, start = "", None
    return out


def split(text: str) -> list:
    lexer = shlex.shlex(text, posix=True, punctuation_chars=False)
    lexer.whitespace_split, lexer.commenters = True, "#"
    return list(lexer)


def unquoted(text: str) -> str:
    return re.sub(r"'[^']*'|\"[^\"]*\"", "''", text.split(" #")[0])


def is_synopsis(command: str) -> bool:
    return bool(re.search(r"[\[\]|()]|\.\.\.|…", unquoted(command)))


def placeholders(tokens) -> list:
    return [t for t in tokens
            if "$" in t or any(p in PLACEHOLDER_WORDS for p in re.split(r"[=,./:]", t))]


def is_fitlab_line(text: str) -> bool:
    """A fitlab command (not a message that starts with "fitlab info: error: ...")."""
    return bool(re.match(r"fitlab [^\s:]+(\s|$)", text))


def is_command_block(block: Block) -> bool:
    return block.lang == "bash" or (block.lang == "" and is_fitlab_line(block.first))


def free_names(source: str) -> set:
    """Names a python block reads but neither assigns nor imports."""
    tree = ast.parse(source)
    bound, used = set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            (used if isinstance(node.ctx, ast.Load) else bound).add(node.id)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            bound.update((a.asname or a.name).split(".")[0] for a in node.names)
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            bound.add(node.name)
        elif isinstance(node, ast.arg):
            bound.add(node.arg)
    return used - bound - set(dir(builtins))


def python_source(block: Block) -> str:
    """The block's code, placed at its line numbers in the document (for tracebacks)."""
    return "\n" * block.line + "\n".join(t for _, t in block.lines) + "\n"


# --------------------------------------------------------------------------------------------
# Units: what runs
# --------------------------------------------------------------------------------------------


class Unit(NamedTuple):
    doc: str
    line: int
    kind: str  # python | command | mkdir | data
    key: str  # the command after `fitlab` (or "python:<first line>", the data handler, ...)
    argvs: tuple  # command: the argument lists to run; python: (Block,); data: (Block,)
    slow: bool

    @property
    def id(self) -> str:
        return f"{self.doc}:{self.line}"


def _cost_is_quick(argv) -> bool:
    """Reading, listing, help and conversion into fitlab's CSV: no model is compiled."""
    return bool(argv) and (argv[0] in QUICK_SUBCOMMANDS or "--help" in argv or (
        argv[0] == "convert" and argv[-1].endswith(".csv") and "--model" not in argv
        and not argv[1].endswith(".json")))


def _command_argvs(rest: list) -> list:
    """The argument lists a fitlab line (tokens after `fitlab`) runs, placeholders replaced."""
    argvs = [[]]
    for tok in rest:
        value = PLACEHOLDERS.get(tok, tok)
        if value == "EVERY_COMMAND":
            from fitlab.cli import COMMANDS

            argvs = [a + [c] for a in argvs for c in COMMANDS]
        else:
            argvs = [a + [value] for a in argvs]
    return argvs


def classify(block: Block) -> tuple:
    """(units, problems, checked): what runs, why the block cannot be handled, and the fitlab
    lines checked against the parser without running, with the reason."""
    units, problems, checked = [], [], []
    if block.lang == "python":
        src = "\n".join(t for _, t in block.lines)
        try:
            ast.parse(src)
        except SyntaxError as exc:
            return [], [f"{block.id}: not valid Python ({exc}); write real code, or name the "
                        "placeholder in a table of this test"], []
        key = f"python:{block.first}"
        quick = any(block.doc == d and block.first.startswith(f) for d, f in QUICK_PYTHON)
        units.append(Unit(block.doc, block.line, "python", key, (block,), not quick))
        return units, problems, checked
    if is_command_block(block):
        check_only = CHECK_ONLY_DOCS.get(block.doc)
        for n, text in logical_lines(block):
            where = f"{block.doc}:{n}"
            mkdir = re.fullmatch(r"mkdir -p (\S+)", text)
            if mkdir:
                units.append(Unit(block.doc, n, "mkdir", text, ((mkdir.group(1),),), False))
                continue
            setup = re.search(r"(?:^|&& )\.venv/bin/(fitlab .*)$", text)
            if not is_fitlab_line(text):
                reason = next((r for p, r in SHELL_LINES if re.match(p, text)), None)
                if reason is None:
                    problems.append(f"{where}: a shell line this test does not know: {text!r}; "
                                    "add it to SHELL_LINES with the reason it is not run")
                elif setup:
                    checked.append((where, setup.group(1), reason))
                continue
            command = text[len("fitlab "):]
            if is_synopsis(command):
                checked.append((where, text, "a usage synopsis"))
                continue
            key = " ".join(command.split(" #")[0].split())
            if check_only or key in NOT_RUN:
                checked.append((where, text, check_only or NOT_RUN[key]))
                continue
            rest = split(command)
            left = [t for t in placeholders(rest) if t not in PLACEHOLDERS]
            if left:
                problems.append(f"{where}: placeholders {left} in {text!r}: replace them in "
                                "PLACEHOLDERS, or say in NOT_RUN why the line does not run")
                continue
            argvs = _command_argvs(rest)
            need = NEEDS.get((block.doc, key))
            slow = not all(_cost_is_quick(a) for a in argvs) or need is not None
            units.append(Unit(block.doc, n, "command", key, tuple(argvs), slow))
        return units, problems, checked
    for (doc, start), handler in DATA_BLOCKS.items():
        if doc == block.doc and block.first.startswith(start):
            if not handler.startswith("skip:"):
                units.append(Unit(block.doc, block.line, "data", handler, (block,), False))
            return units, problems, checked
    return [], [f"{block.id}: a {block.lang or 'plain'} block this test cannot classify "
                f"(first line {block.first!r}): make it runnable or add it to DATA_BLOCKS"], []


@lru_cache(maxsize=None)
def all_blocks() -> tuple:
    return tuple(b for doc in DOCS for b in blocks(doc))


@lru_cache(maxsize=None)
def all_units() -> tuple:
    return tuple(u for b in all_blocks() for u in classify(b)[0])


# --------------------------------------------------------------------------------------------
# Checking a command line against the parser
# --------------------------------------------------------------------------------------------


@lru_cache(maxsize=1)
def parser():
    from fitlab.cli import build_parser

    return build_parser()


def _options(sub) -> dict:
    return {s: a for a in sub._actions for s in a.option_strings}


def check_synopsis(text: str) -> list:
    """Problems of a usage line: its subcommand, every --option it names and every choice it
    lists (``--loss chi2|relative``) must be the parser's."""
    from fitlab.fitting.compare.candidates import CANDIDATE_FLAGS

    try:
        tokens = split(text)[1:]
    except ValueError:
        tokens = unquoted(text).split()[1:]
    words = [t.strip("[]()") for t in tokens]
    name = next((w for w in words if w and not w.startswith("-")), None)
    if name in PLACEHOLDER_WORDS:  # fitlab COMMAND --help: every subcommand
        from fitlab.cli import COMMANDS

        return [p for c in COMMANDS
                for p in check_synopsis(text.replace(" " + name + " ", f" {c} ", 1))]
    sub = parser().subcommand(name)
    if sub is parser():
        return [f"no subcommand {name!r}"]
    options, problems = _options(sub), []
    for i, (tok, word) in enumerate(zip(tokens, words)):
        if " " in tok and "--" in tok:  # a compare candidate: 'NAME [--fix P=V] ...'
            bad = [f for f in re.findall(r"--[\w-]+", tok) if f not in CANDIDATE_FLAGS]
            problems += [f"{f} is not a candidate option of `fitlab {name}`" for f in bad]
            continue
        if not word.startswith("--"):
            continue
        flag = word.split("=")[0]
        if flag not in options:
            problems.append(f"`fitlab {name}` has no option {flag}")
            continue
        choices = options[flag].choices
        nxt = words[i + 1] if i + 1 < len(words) else ""
        if choices is not None and "|" in nxt and "=" not in nxt:
            for alt in nxt.split("|"):
                alt = alt.strip("[]()")
                if alt and alt not in PLACEHOLDER_WORDS and alt not in map(str, choices):
                    problems.append(f"{alt!r} is not a choice of {flag} ({list(choices)})")
    return problems


def check_parses(argv: list) -> list:
    """Problems of a whole command line: the parser must take it as it is."""
    import io

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            args, extras = parser().parse_known_args(argv)
    except SystemExit as exc:
        if exc.code == 0:  # --help
            return []
        return [err.getvalue().strip().splitlines()[-1] if err.getvalue() else str(exc)]
    return [f"unrecognized arguments {extras}"] if extras else []


def check_line(text: str) -> list:
    command = text[len("fitlab "):]
    if is_synopsis(command):
        return check_synopsis(text)
    argvs = _command_argvs(split(command))
    return check_synopsis(text) + [p for a in argvs for p in check_parses(a)]


# --------------------------------------------------------------------------------------------
# Running: one working folder per document
# --------------------------------------------------------------------------------------------


def git_status():
    """The repository's ``git status --porcelain`` (None outside a git checkout)."""
    if not (ROOT / ".git").exists() or not os.path.exists(GIT):
        return None
    return subprocess.run([GIT, "-C", str(ROOT), "status", "--porcelain"], check=True,
                          capture_output=True, text=True).stdout


def not_ignored(paths) -> list:
    """Of ``paths`` (relative to the repository), those the repository does not ignore."""
    if not paths or not (ROOT / ".git").exists():
        return []
    r = subprocess.run([GIT, "-C", str(ROOT), "check-ignore", "--no-index", "--stdin"],
                       input="\n".join(paths) + "\n", capture_output=True, text=True)
    ignored = set(r.stdout.splitlines())
    return [p for p in paths if p not in ignored]


def snapshot(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def files(folder: Path) -> list:
    return [p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()]


_WORK: dict = {}  # document -> {"dir": Path, "done": set, "namespace": dict}


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    def get(doc: str) -> dict:
        if doc not in _WORK:
            d = tmp_path_factory.mktemp(re.sub(r"\W", "_", doc))
            for name in INPUT_FOLDERS:
                shutil.copytree(ROOT / name, d / name,
                                ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
            _WORK[doc] = {"dir": d, "done": set(), "namespace": None}
        return _WORK[doc]
    yield get
    _WORK.clear()


def _run_argv(argv: list, where: str) -> None:
    from fitlab.cli import main

    argv = [m for a in argv for m in (sorted(glob.glob(a)) or [a] if "*" in a else [a])]
    try:
        rc = main(argv)
    except SystemExit as exc:  # --help
        rc = exc.code
    assert rc == 0, f"{where}: `fitlab {shlex.join(argv)}` exited {rc}"


def _run_python(block: Block, state: dict) -> None:
    src = "\n".join(t for _, t in block.lines)
    if free_names(src):
        assert state["namespace"] is not None, (
            f"{block.id}: uses {sorted(free_names(src))} but no python block before it in "
            f"{block.doc} defines them")
        namespace = state["namespace"]
    else:
        namespace = {"__name__": "__doc_example__"}
    mi = __import__("sys").modules.get("mitsuba")
    variant = mi.variant() if mi is not None else None
    try:
        exec(compile(python_source(block), str(ROOT / block.doc), "exec"), namespace)
    finally:
        mi = __import__("sys").modules.get("mitsuba")
        if variant is not None and mi is not None and mi.variant() != variant:
            mi.set_variant(variant)
    state["namespace"] = namespace


def _run_data(unit: Unit, folder: Path) -> None:
    (block,) = unit.argvs
    text = "\n".join(t for _, t in block.lines) + "\n"
    if unit.key == "scene":
        from fitlab.simulate import load_scene

        path = folder / "scene_block.toml"
        path.write_text(text, encoding="utf-8")
        load_scene(path)
    elif unit.key == "sweep":
        from fitlab.simulate.sweep import load_sweep

        # the block shows examples/sweeps/coated_lambertian_grid.toml: same base scene and grid
        path = folder / "data_formats" / "examples" / "sweeps" / "sweep_block.toml"
        path.write_text(text, encoding="utf-8")  # where its base scene's relative path leads
        try:
            got = load_sweep(path)
        finally:
            path.unlink()
        want = load_sweep(path.with_name("coated_lambertian_grid.toml"))
        assert (got.base, got.keys, got.points, got.samples) == \
            (want.base, want.keys, want.points, want.samples), block.id
    elif unit.key == "directions":
        from fitlab.io.directions import read_directions

        path = folder / "directions_block.csv"
        path.write_text(text, encoding="utf-8")
        assert len(read_directions(path).theta_i) == len(block.lines) - 2
    elif unit.key in ("measurement", "values"):
        import numpy as np

        import fitlab

        path = folder / f"{unit.key}_block.csv"
        path.write_text(text, encoding="utf-8")
        m = fitlab.read(path)
        if unit.key == "values":  # the values shown are the model's, to the digits printed
            meta = m.metadata
            params = {k: float(v) for k, v in
                      (kv.split("=") for kv in meta["parameters"].split(", "))}
            options = dict(kv.split("=") for kv in meta["options"].split(", "))
            f = fitlab.eval_bsdf(meta["model"], params, m.wi, m.wo, options)
            np.testing.assert_allclose(np.asarray(f), m.value, rtol=1e-9)
    else:
        raise AssertionError(f"{unit.id}: no handler {unit.key!r}")


def _find_unit(doc: str, key: str):
    for u in all_units():
        if u.doc == doc and u.key == key:
            return u
    return None


def run_unit(unit: Unit, state: dict) -> None:
    if unit.key in state["done"]:
        return
    folder = state["dir"]
    need = NEEDS.get((unit.doc, unit.key))
    if need and need.startswith("copy "):
        src, dst = need.split()[1:]
        shutil.copyfile(folder / src, folder / dst)
    elif need:
        producer = _find_unit(unit.doc, need)
        if producer is not None:
            run_unit(producer, state)
        else:
            with contextlib.chdir(folder):
                _run_argv(split(need), f"{unit.id} (needs)")
    for earlier in all_units():  # the document's `mkdir -p` lines above it
        if earlier.doc == unit.doc and earlier.kind == "mkdir" and earlier.line < unit.line:
            os.makedirs(folder / earlier.argvs[0][0], exist_ok=True)
    with contextlib.chdir(folder):
        if unit.kind == "mkdir":
            os.makedirs(unit.argvs[0][0], exist_ok=True)
        elif unit.kind == "command":
            for argv in unit.argvs:
                for tok in argv:  # a replaced output path's folder (the line shows none)
                    if tok in PLACEHOLDERS.values() and "/" in tok:
                        os.makedirs(os.path.dirname(tok), exist_ok=True)
                _run_argv(list(argv), unit.id)
        elif unit.kind == "python":
            previous = [u for u in all_units()
                        if u.doc == unit.doc and u.kind == "python" and u.line < unit.line]
            src = "\n".join(t for _, t in unit.argvs[0].lines)
            if free_names(src) and previous and previous[-1].key not in state["done"]:
                run_unit(previous[-1], state)  # the block it continues
            _run_python(unit.argvs[0], state)
        else:
            _run_data(unit, folder)
    state["done"].add(unit.key)


# --------------------------------------------------------------------------------------------
# The tests
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("block", all_blocks(), ids=lambda b: b.id)
def test_block_is_classified(block):
    """Every block is python, commands or a data block of the table; every fitlab line names a
    subcommand, options and choices that exist (parsed whole where it is not a synopsis)."""
    units, problems, checked = classify(block)
    assert not problems, "\n".join(problems)
    for where, text, reason in checked:
        assert reason, where
        bad = check_line(text)
        assert not bad, f"{where}: {text!r}: " + "; ".join(bad)
    for unit in units:
        if unit.kind == "command":
            for argv in unit.argvs:
                bad = check_synopsis("fitlab " + shlex.join(argv)) + check_parses(list(argv))
                assert not bad, f"{unit.id}: {argv}: " + "; ".join(bad)
    if block.lang == "python":  # a fragment continues a python block before it
        missing = free_names("\n".join(t for _, t in block.lines))
        if missing:
            before = [b for b in all_blocks()
                      if b.doc == block.doc and b.lang == "python" and b.line < block.line]
            assert before, f"{block.id}: uses {sorted(missing)}, defined by no block before it"
            defined = set()
            for b in before:
                src = "\n".join(t for _, t in b.lines)
                tree = ast.parse(src)
                defined |= {n.id for n in ast.walk(tree)
                            if isinstance(n, ast.Name) and not isinstance(n.ctx, ast.Load)}
                defined |= {(a.asname or a.name).split(".")[0] for n in ast.walk(tree)
                            if isinstance(n, (ast.Import, ast.ImportFrom)) for a in n.names}
            assert missing <= defined, f"{block.id}: {sorted(missing - defined)} undefined"


def unit_text(unit) -> str:
    """The source a unit runs (its blocks' lines, or its command lines)."""
    return "\n".join(t for a in unit.argvs for t in (
        [line for _, line in a.lines] if hasattr(a, "lines") else [" ".join(map(str, a))]))


def _release_render_memory() -> None:
    """Hand Dr.Jit's memory (its allocation cache and compiled kernels) back after a render."""
    import sys

    dr = sys.modules.get("drjit")
    if dr is not None:
        dr.sync_thread()
        dr.flush_malloc_cache()
        dr.flush_kernel_cache()


@pytest.mark.parametrize("unit", [pytest.param(u, id=u.id, marks=[pytest.mark.slow] * u.slow)
                                  for u in all_units()])
def test_example_runs(unit, work):
    """The unit runs verbatim in its document's working folder, changes none of the copied
    inputs and nothing in the checkout, and (README) writes only files the repository ignores."""
    state = work(unit.doc)
    folder = state["dir"]
    status, inputs = git_status(), {n: snapshot(folder / n) for n in INPUT_FOLDERS}
    before = set(files(folder))
    renders = "mitsuba" in unit_text(unit)
    if renders:  # a Mitsuba render takes about 2.4 GB: not on top of the worker's compiled code
        from conftest import _release_compiled_code

        _release_compiled_code()
    try:
        run_unit(unit, state)
    finally:
        if renders:
            _release_render_memory()
    for name in INPUT_FOLDERS:
        after = snapshot(folder / name)
        written = sorted(f"{name}/{k}" for k in set(inputs[name]) | set(after)
                         if inputs[name].get(k) != after.get(k))
        assert not written, f"{unit.id} wrote into the bundled inputs: {written}"
    now = git_status()
    assert now == status, (  # (in a tree others edit meanwhile, their edits show here too)
        f"{unit.id} changed the checkout: git status --porcelain gained "
        f"{sorted(set(now.splitlines()) - set(status.splitlines()))} and lost "
        f"{sorted(set(status.splitlines()) - set(now.splitlines()))}")
    if unit.doc in CLEAN_CHECKOUT_DOCS:
        new = sorted(set(files(folder)) - before)
        assert not not_ignored(new), (
            f"{unit.id} writes files the repository does not ignore: {not_ignored(new)}; "
            "write under out/")


def test_tables_name_what_the_documents_hold():
    """No stale entries: every NOT_RUN line, NEEDS consumer and DATA_BLOCKS block is in a
    document (a line that changed is classified again)."""
    keys = set()
    for block in all_blocks():
        if is_command_block(block):
            keys |= {" ".join(t[len("fitlab "):].split(" #")[0].split())
                     for _, t in logical_lines(block) if is_fitlab_line(t)}
    assert not set(NOT_RUN) - keys, f"NOT_RUN names lines no document has: {set(NOT_RUN) - keys}"
    units = {(u.doc, u.key) for u in all_units()}
    assert not set(NEEDS) - units, f"NEEDS names no unit: {set(NEEDS) - units}"
    firsts = {(b.doc, s) for b in all_blocks() for (d, s) in DATA_BLOCKS
              if b.doc == d and b.first.startswith(s)}
    assert not set(DATA_BLOCKS) - firsts, f"DATA_BLOCKS: {set(DATA_BLOCKS) - firsts}"
