"""The package's layers (fitlab/LAYERS.md): no import reaches a higher layer or closes a cycle,
counting the imports inside functions; no module of the library imports the package root."""

from __future__ import annotations

import ast
import fnmatch
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "fitlab"


def layer_table(text: str) -> list[tuple[str, list[str]]]:
    """[(layer, [module patterns])] from LAYERS.md's table, lowest layer first."""
    rows = []
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 2 and cells[0] not in ("layer", "") and not set(cells[0]) <= set("-"):
            rows.append((cells[0], re.findall(r"`([^`]+)`", cells[1])))
    return rows


def modules(package: Path) -> dict[str, Path]:
    """{dotted name below fitlab ("" for the root): file}."""
    out = {}
    for path in package.rglob("*.py"):
        parts = list(path.relative_to(package).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def imports(source: str, known) -> set[str]:
    """The fitlab modules ``source`` imports, anywhere in it (a name imported from a package is
    the submodule when it is one, else the package)."""
    def resolve(dotted: str) -> str:
        parts = dotted.split(".")[1:]
        while parts and ".".join(parts) not in known:
            parts = parts[:-1]
        return ".".join(parts)

    out = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out |= {resolve(a.name) for a in node.names
                    if a.name == "fitlab" or a.name.startswith("fitlab.")}
        elif (isinstance(node, ast.ImportFrom) and node.level == 0 and node.module
              and (node.module == "fitlab" or node.module.startswith("fitlab."))):
            for a in node.names:
                sub = resolve(f"{node.module}.{a.name}")
                out.add(sub if sub == f"{node.module}.{a.name}"[len("fitlab."):]
                        else resolve(node.module))
    return out


def layer_of(table, name: str) -> int:
    shown = name or "fitlab"
    for i, (_, patterns) in enumerate(table):
        if any(fnmatch.fnmatchcase(shown, p) for p in patterns):
            return i
    raise LookupError(f"fitlab.{name} is in no layer of fitlab/LAYERS.md: add it to the table")


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


@pytest.fixture(scope="module")
def graph():
    known = modules(PACKAGE)
    return {name: imports(path.read_text(encoding="utf-8"), known) - {name}
            for name, path in known.items()}


@pytest.fixture(scope="module")
def table():
    return layer_table((PACKAGE / "LAYERS.md").read_text(encoding="utf-8"))


def test_every_module_has_a_layer(graph, table):
    assert [name for name, _ in table][:3] == ["base", "physics", "models"]
    for name in graph:
        layer_of(table, name)


def test_no_import_reaches_a_higher_layer(graph, table):
    upward = [f"fitlab.{m or '(root)'} ({table[layer_of(table, m)][0]}) imports "
              f"fitlab.{o or '(root)'} ({table[layer_of(table, o)][0]})"
              for m, outs in sorted(graph.items()) for o in sorted(outs)
              if layer_of(table, o) > layer_of(table, m)]
    assert not upward, "\n".join(upward)


def test_no_import_cycle(graph):
    assert not cycles(graph), cycles(graph)


def test_the_checks_see_what_they_should(table):
    """The scanner finds imports inside functions and names imported from a package, and the
    checks catch a cycle and an upward import."""
    known = {"", "errors", "models", "models.base", "report", "report.build"}
    src = ("import fitlab\nfrom fitlab.models import base, get_model\n"
           "def f():\n    from fitlab.report import build\n    import fitlab.errors\n")
    assert imports(src, known) == {"", "models.base", "models", "report.build", "errors"}
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert layer_of(table, "models.base") < layer_of(table, "report.build")
    assert layer_of(table, "") == len(table) - 1  # the root: nothing below imports it
    with pytest.raises(LookupError, match="no layer"):
        layer_of(table, "a_module_nobody_placed")


def test_only_fitlab_jax_imports_jax():
    """fitlab/_jax.py is fitlab's one way to JAX: every module reaches JAX through it, so JAX
    loads at its first use and fitlab's settings (float64, no asynchronous CPU dispatch) are in
    place before any fitlab code computes (issue 34 item 7)."""
    hits = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path == PACKAGE / "_jax.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or ""]
            else:
                continue
            hits += [f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: import {n}"
                     for n in names if n == "jax" or n.startswith("jax.")]
    assert not hits, "use `from fitlab._jax import jax, jnp`:\n" + "\n".join(hits)


# --------------------------------------------------------------------------------------------
# Names are not structure: a model carries its structure (Model.terms, .inner, .arguments,
# .translations); outside fitlab/models/ nothing parses or compares a model's name
# --------------------------------------------------------------------------------------------

#: the name-syntax functions of fitlab/models/syntax.py
NAME_PARSERS = {"parse_call", "split_top_level", "call_arguments"}


def _model_ish(node) -> bool:
    """An expression that is a model (get_model(...), model, mdl, ctx.model, ...)."""
    if isinstance(node, ast.Call):
        f = node.func
        return (f.id if isinstance(f, ast.Name) else getattr(f, "attr", "")) == "get_model"
    text = ast.unparse(node).lower()
    return "model" in text or text in ("mdl", "m")


def name_branches(source: str) -> list[str]:
    """Where ``source`` compares or parses a model's name."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare) and all(
                isinstance(op, (ast.Eq, ast.NotEq, ast.In, ast.NotIn)) for op in node.ops):
            for side in (node.left, *node.comparators):
                if isinstance(side, ast.Attribute) and (
                        (side.attr == "name" and _model_ish(side.value))
                        or side.attr in ("func", "model")):
                    out.append(f"line {node.lineno}: {ast.unparse(side)} compared")
                    break
        elif isinstance(node, ast.Call):
            f = node.func
            name = f.id if isinstance(f, ast.Name) else getattr(f, "attr", None)
            if name in NAME_PARSERS:
                out.append(f"line {node.lineno}: {name}(...)")
            elif name == "startswith" and node.args:
                arg = node.args[0]
                for lit in (arg.elts if isinstance(arg, (ast.Tuple, ast.List)) else [arg]):
                    if isinstance(lit, ast.Constant) and isinstance(lit.value, str) \
                            and "(" in lit.value:
                        out.append(f"line {node.lineno}: .startswith({lit.value!r})")
    return out


def test_no_model_name_is_parsed_or_compared_outside_models():
    hits = [f"{path.relative_to(PACKAGE.parent)}: {hit}"
            for path in sorted(PACKAGE.rglob("*.py"))
            if "models" not in path.relative_to(PACKAGE).parts[:1]
            for hit in name_branches(path.read_text(encoding="utf-8"))]
    assert not hits, "\n".join(hits)


def test_the_name_check_sees_what_it_should():
    src = ("if get_model(a).name != get_model(b).name: pass\n"
           "if material.model in NATIVE: pass\n"
           "call = parse_call(x)\n"
           "ok = p.model.startswith('spongecake(')\n"
           "fine = knob.name in wanted\n")
    assert [h.split(":")[0] for h in name_branches(src)] == ["line 1", "line 2", "line 3",
                                                             "line 4"]
