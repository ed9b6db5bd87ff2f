"""Pydantic's validation errors as forest's one-line messages: a dotted field and plain words.

``('species', 1, 'percent')`` becomes ``species[1].percent``; an element of a
number vector (``terrain.size[0]``) is reported on the vector, with its whole
value; ``extra_forbidden`` lists the keys the table takes.  Custom errors of
the schema (type ``forest``) carry their message, and ``forest_field`` names a
sub-field of the table that raised it.
"""

from __future__ import annotations

import typing
from typing import Any

from pydantic import BaseModel, ValidationError

from .schema import SceneConfig

#: What a missing required table needs, said where "is required" would not help.
MISSING = {
    "terrain": "is required: give exactly one terrain source (heightmap, mesh, procedural or flat)",
    "species": "at least one [[species]] is required",
}


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return repr(v)


def _whole_number(v: Any) -> str:
    """The message for a value that is not an integer; ``64.0`` is told to lose its decimal point (TOML reads
    ``64.0`` as a float, and ``{v:g}`` would print it as 64)."""
    if isinstance(v, float) and v.is_integer():
        return f"must be a whole number without a decimal point, got {v!r}"
    return f"must be a whole number, got {_fmt(v)}"


def dotted(loc: tuple[Any, ...] | list[Any]) -> str:
    """``('species', 1, 'percent')`` → ``species[1].percent``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else str(part)
    return out


def _value_at(data: Any, loc: tuple[Any, ...]) -> Any:
    node = data
    for part in loc:
        try:
            node = node[part]
        except (KeyError, IndexError, TypeError):
            return None
    return node


def _model_at(loc: tuple[Any, ...]) -> type[BaseModel] | None:
    """The schema model of the table at ``loc`` (None when it is not a table)."""
    model: Any = SceneConfig
    for part in loc:
        if isinstance(part, int):
            continue
        if not (isinstance(model, type) and issubclass(model, BaseModel)) or part not in model.model_fields:
            return None
        model = _unwrap(model.model_fields[part].annotation)
    return model if isinstance(model, type) and issubclass(model, BaseModel) else None


def _unwrap(annotation: Any) -> Any:
    stack = [annotation]
    while stack:
        a = stack.pop()
        if isinstance(a, type) and issubclass(a, BaseModel):
            return a
        stack.extend(x for x in typing.get_args(a) if x is not type(None))
    return annotation


def first_error(error: ValidationError, data: Any) -> tuple[str | None, str]:
    """(dotted field or None, message) of the first error pydantic reports — except that a required key reported
    missing gives way to an unknown key of the same table, the likelier mistake (a misspelt name)."""
    errors = error.errors(include_url=False)
    e = errors[0]
    if e["type"] == "missing":
        parent = tuple(e["loc"][:-1])
        e = next((x for x in errors if x["type"] == "extra_forbidden" and tuple(x["loc"][:-1]) == parent), e)
    loc = tuple(p for p in e["loc"] if not (isinstance(p, str) and ("[" in p or "-" in p)))
    kind = e["type"]
    ctx = e.get("ctx") or {}
    value = e.get("input")

    if kind == "forest_field":
        sub = str(ctx["field"])
        table = dotted(loc)
        return (f"{table}.{sub}" if table else sub), e["msg"]
    if kind == "forest":
        return (dotted(loc) or None), e["msg"]
    if kind == "extra_forbidden":
        model = _model_at(loc[:-1])
        keys = sorted(model.model_fields) if model is not None else []
        hint = f" (expected one of: {', '.join(keys)})" if keys else ""
        return dotted(loc), f"unknown key{hint}"

    # An element of a number vector: name the vector and show its whole value.
    prefix = "must be"
    if loc and isinstance(loc[-1], int):
        parent = _value_at(data, loc[:-1])
        if isinstance(parent, list) and not any(isinstance(x, dict) for x in parent):
            loc = loc[:-1]
            if kind == "missing":
                kind, value = "vector", parent
            else:
                prefix = "values must be"
                value = (
                    parent
                    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal", "finite_number")
                    else value
                )
    field = dotted(loc) or None

    messages = {
        "missing": "is required",
        "int_type": _whole_number(value),
        "int_parsing": _whole_number(value),
        "int_from_float": _whole_number(value),
        "float_type": f"must be a number, got {_fmt(value)}",
        "float_parsing": f"must be a number, got {_fmt(value)}",
        "bool_type": f"must be true or false, got {_fmt(value)}",
        "bool_parsing": f"must be true or false, got {_fmt(value)}",
        "string_type": f"must be a string, got {_fmt(value)}",
        "string_too_short": "must be a non-empty string",
        "finite_number": f"{prefix} finite, got {_fmt(value)}",
        "greater_than_equal": f"{prefix} >= {_fmt(ctx.get('ge'))}, got {_fmt(value)}",
        "greater_than": f"{prefix} > {_fmt(ctx.get('gt'))}, got {_fmt(value)}",
        "less_than_equal": f"{prefix} <= {_fmt(ctx.get('le'))}, got {_fmt(value)}",
        "less_than": f"{prefix} < {_fmt(ctx.get('lt'))}, got {_fmt(value)}",
        "literal_error": f"must be one of {ctx.get('expected')}; got {_fmt(value)}",
        "model_type": f"must be a table, got {_fmt(value)}",
        "model_attributes_type": f"must be a table, got {_fmt(value)}",
        "dict_type": f"must be a table, got {_fmt(value)}",
        "list_type": f"must be an array, got {_fmt(value)}",
        "tuple_type": f"must be a list of numbers, got {_fmt(value)}",
        "vector": f"has too few values, got {_fmt(value)}",
        "too_short": f"must have at least {ctx.get('min_length')} item(s), got {_fmt(value)}",
        "too_long": f"must have at most {ctx.get('max_length')} item(s), got {_fmt(value)}",
    }
    if kind == "missing" and field in MISSING:
        return field, MISSING[field]
    if kind in messages:
        return field, messages[kind]
    msg = e["msg"]
    for lead in ("Value error, ", "Assertion failed, "):
        if msg.startswith(lead):
            msg = msg[len(lead) :]
    return field, msg[:1].lower() + msg[1:]
