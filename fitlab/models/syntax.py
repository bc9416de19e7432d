"""Model-name syntax: registry names, sums ``a+b`` and layered constructors ``f(arg,key=value)``.

    lambertian+rough_conductor                  sum (models/composite.py)
    coated(rough_conductor)                     any registry model under a smooth coat
    coated(lambertian+rough_conductor)          ... including sums (the '+' inside parentheses
                                                belongs to the argument)
    coated(lambertian,specular=lobe)            keyword arguments after the model argument
    weidlich_wilkie(oren_nayar,layers=3)
    lambertian+coated(rough_conductor)          constructors are terms of sums too

Whitespace is ignored. Parsing only splits the text; get_model resolves the names.
"""

from __future__ import annotations

from typing import NamedTuple


class Call(NamedTuple):
    func: str
    args: tuple[str, ...]
    kwargs: tuple[tuple[str, str], ...]


def _check_balanced(name: str) -> None:
    depth = 0
    for ch in name:
        depth += (ch == "(") - (ch == ")")
        if depth < 0:
            break
    if depth != 0:
        raise ValueError(f"model name {name!r} has unbalanced parentheses")


def split_top_level(text: str, sep: str) -> list[str]:
    """Split at ``sep`` outside parentheses."""
    _check_balanced(text)
    parts, depth, cur = [], 0, []
    for ch in text:
        if ch == "(":
            depth += 1
        elif ch == ")":
            depth -= 1
        if ch == sep and depth == 0:
            parts.append("".join(cur).strip())
            cur = []
        else:
            cur.append(ch)
    parts.append("".join(cur).strip())
    if any(not p for p in parts):
        raise ValueError(f"model name {text!r} has an empty term around {sep!r}")
    return parts


def parse_call(text: str) -> Call | None:
    """``func(arg, ..., key=value, ...)`` → Call; None for a plain name."""
    text = "".join(text.split())
    if "(" not in text:
        return None
    _check_balanced(text)
    head, _, rest = text.partition("(")
    if not head.isidentifier() or not rest.endswith(")"):
        raise ValueError(f"model name {text!r}: expected NAME(MODEL[,KEY=VALUE...])")
    inner = rest[:-1]
    args, kwargs = [], []
    for item in split_top_level(inner, ","):
        key, eq, value = item.partition("=")
        if eq and key.isidentifier() and "(" not in key:
            kwargs.append((key, value))
        elif kwargs:
            raise ValueError(f"model name {text!r}: positional argument {item!r} after a "
                             "keyword argument")
        else:
            args.append(item)
    return Call(head, tuple(args), tuple(kwargs))


def call_arguments(call: Call, usage: str, keywords: dict[str, str]) -> tuple[str, dict[str, str]]:
    """The one model argument and the keyword arguments of a layered constructor.

    ``usage`` shows a correct call (e.g. ``coated(rough_conductor)``); ``keywords`` maps each
    accepted keyword to the text that explains it in an error (e.g. ``"specular=delta|lobe"``).
    """
    kwargs = dict(call.kwargs)
    if len(call.args) != 1:
        raise ValueError(f"{call.func}(...) takes one model, e.g. {usage}; got {len(call.args)}")
    unknown = set(kwargs) - set(keywords)
    if unknown:
        raise ValueError(f"{call.func}(...): unknown keyword(s) {', '.join(sorted(unknown))}; "
                         f"accepted: {', '.join(keywords.values())}")
    return call.args[0], kwargs
