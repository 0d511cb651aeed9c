"""Where in the file a config error is: the key path as the user wrote it, its line, and a
"did you mean" for an unknown key.

Pure. ``swarm.config.resolve`` layers ``defaults`` and ``agent_types`` into every agent
before validating, so a validation error names the merged path (``agents.0.filter.gama``);
:func:`written` finds the key the user wrote (``defaults.filter.gama``) and
:func:`key_lines` its line in the YAML text.
"""

from __future__ import annotations

import difflib
import types
from collections.abc import Sequence
from typing import Any, NamedTuple, Union, get_args, get_origin

import yaml
from pydantic import BaseModel

Loc = tuple[str | int, ...]


class Where(NamedTuple):
    """A key path as written in the file, and its line (1-based; None: not in the file)."""

    path: Loc
    line: int | None


def key_lines(text: str) -> dict[Loc, int]:
    """The line (1-based) of every key and list item of the YAML ``text``, by its path
    (``("defaults", "filter", "gama")``, ``("agents", 0)``). Empty when the text does not parse."""
    try:
        root = yaml.compose(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except yaml.YAMLError:
        return {}
    out: dict[Loc, int] = {}

    def walk(node: Any, path: Loc) -> None:
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                key = k.value if isinstance(k, yaml.ScalarNode) else str(k.value)
                out[(*path, key)] = k.start_mark.line + 1
                walk(v, (*path, key))
        elif isinstance(node, yaml.SequenceNode):
            for i, v in enumerate(node.value):
                out[(*path, i)] = v.start_mark.line + 1
                walk(v, (*path, i))

    if root is not None:
        walk(root, ())
    return out


def _has(raw: Any, path: Sequence[str | int]) -> bool:
    node = raw
    for p in path:
        if isinstance(node, dict) and p in node:
            node = node[p]
        elif isinstance(node, list) and isinstance(p, int) and 0 <= p < len(node):
            node = node[p]
        else:
            return False
    return True


def written(raw: Any, loc: Loc, lines: dict[Loc, int]) -> Where:
    """Where the user wrote the value an error at the merged path ``loc`` is about: in the
    file's own agent entry, else its agent type, else ``defaults`` (the layers
    ``swarm.config.resolve`` merges, most specific first); the longest prefix of the path
    that is in the file when the key itself is not (a missing key: its mapping)."""
    candidates: list[Loc] = [loc]
    if len(loc) >= 3 and loc[0] == "agents" and isinstance(loc[1], int):
        rest = loc[2:]
        agents = raw.get("agents") if isinstance(raw, dict) else None
        entry = agents[loc[1]] if isinstance(agents, list) and 0 <= loc[1] < len(agents) else None
        tname = entry.get("type") if isinstance(entry, dict) else None
        if isinstance(tname, str):
            candidates.append(("agent_types", tname, *rest))
        candidates.append(("defaults", *rest))
    for c in candidates:
        if _has(raw, c):
            return Where(c, lines.get(c))
    for n in range(len(loc), 0, -1):  # not written: the nearest mapping that is
        if loc[:n] in lines:
            return Where(loc, lines[loc[:n]])
    return Where(loc, None)


def _model_of(annotation: Any) -> type[BaseModel] | None:
    """The pydantic model an annotation holds (through Optional, list, dict values)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    if get_origin(annotation) in (Union, types.UnionType, list, tuple, dict):
        for arg in get_args(annotation):
            found = _model_of(arg)
            if found is not None:
                return found
    return None


def fields_at(model: type[BaseModel], loc: Loc) -> list[str]:
    """The keys the model at path ``loc`` (below ``model``; list indices skipped) takes."""
    current: type[BaseModel] | None = model
    for p in loc:
        if current is None:
            return []
        if isinstance(p, int):
            continue
        field = current.model_fields.get(p)
        current = _model_of(field.annotation) if field is not None else None
    return sorted(current.model_fields) if current is not None else []


def did_you_mean(word: str, choices: Sequence[str]) -> str:
    """`` did you mean 'gamma'?`` for the closest of ``choices``, or nothing."""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


def dotted(path: Loc) -> str:
    return ".".join(str(p) for p in path) or "(top level)"


def explain(errors: Sequence[Any], raw: Any, source: str, lines: dict[Loc, int], model: type[BaseModel]) -> str:
    """One line for a failed validation of ``raw`` (pydantic's ``errors()``): the file and
    line, the key path as written, what is wrong (an unknown key with the closest known one),
    and how many other places are wrong. Errors that land on one written key (a typo in
    ``defaults`` reaches every agent) count once."""
    found: dict[Where, str] = {}
    for e in errors:
        loc: Loc = tuple(e["loc"])
        msg = str(e["msg"]).removeprefix("Value error, ")
        if e["type"] == "value_error" and ": " in msg and msg.split(": ", 1)[0].replace(".", "").isidentifier():
            # our validators name the field below the model they check: "agents.3.start: ..."
            inner, msg = msg.split(": ", 1)
            loc = (*loc, *(int(p) if p.isdigit() else p for p in inner.split(".")))
        if e["type"] == "extra_forbidden" and loc:
            msg = f"unknown key {str(loc[-1])!r}" + did_you_mean(str(loc[-1]), fields_at(model, loc[:-1]))
        found.setdefault(written(raw, loc, lines), msg)
    if not found:
        return f"{source}: invalid"
    (where, msg), *others = found.items()
    at = f"{source}:{where.line}" if where.line is not None else source
    more = f" (and {len(others)} more)" if others else ""
    return f"{at}: {dotted(where.path)}: {msg}{more}"
