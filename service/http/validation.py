"""Messages for malformed requests: each names its field and what that field allows.

FastAPI reports a malformed body as a list of pydantic errors whose `loc` names the
field and whose `msg` says what was wrong ("Input should be greater than 0"). A client
also needs to know what *is* allowed, so every message is rewritten as
`<field>: <what was wrong>; allowed: <what the request schema allows there>`, the
allowance read from the request model's own JSON schema (so it cannot drift from it).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

JsonSchema = dict[str, Any]


def field_path(location: Sequence[str | int]) -> str:
    """`("body", "target", "position", 1)` -> `target.position[1]`; the bare body is `body`."""
    parts = list(location[1:] if location and location[0] == "body" else location)
    path = ""
    for part in parts:
        path += f"[{part}]" if isinstance(part, int) else (f".{part}" if path else part)
    return path or "body"


def _resolve(node: JsonSchema, root: JsonSchema) -> tuple[JsonSchema, bool]:
    """Follow a `$ref` and unwrap `anyOf [X, null]`; returns (X, nullable)."""
    nullable = False
    if "anyOf" in node:
        options = [option for option in node["anyOf"] if option.get("type") != "null"]
        nullable = len(options) < len(node["anyOf"])
        if len(options) == 1:
            node = options[0]
    if "$ref" in node:
        name = node["$ref"].rsplit("/", 1)[-1]
        node = root.get("$defs", {}).get(name, {})
    return node, nullable


def _number(value: float) -> str:
    return f"{value:g}" if isinstance(value, float) and math.isfinite(value) else str(value)


def _bounds(node: JsonSchema) -> str:
    parts = []
    for key, symbol in (
        ("exclusiveMinimum", ">"),
        ("minimum", ">="),
        ("exclusiveMaximum", "<"),
        ("maximum", "<="),
    ):
        if key in node:
            parts.append(f"{symbol} {_number(node[key])}")
    return " and ".join(parts)


def describe(node: JsonSchema, root: JsonSchema, server_limit: str | None = None) -> str:
    """What a JSON-schema node allows, in words; `server_limit` adds a bound from settings."""
    node, nullable = _resolve(node, root)
    kind = node.get("type")
    if "enum" in node:
        text = "one of " + ", ".join(repr(v) for v in node["enum"])
    elif kind in ("number", "integer"):
        text = "a finite number" if kind == "number" else "an integer"
        bounds = " and ".join(b for b in (_bounds(node), server_limit) if b)
        if bounds:
            text += " " + bounds
    elif kind == "string":
        text = "a string"
    elif kind == "boolean":
        text = "true or false"
    elif kind == "array":
        low, high = node.get("minItems"), node.get("maxItems")
        count = (
            f"{low} to {high} "
            if low is not None and high is not None
            else (f"at least {low} " if low is not None else "")
        )
        text = f"a list of {count}values, each {describe(node.get('items', {}), root)}"
    elif kind == "object" or "properties" in node:
        fields = ", ".join(node.get("properties", {}))
        required = ", ".join(node.get("required", []))
        text = f"an object with fields {fields}" + (f" (required: {required})" if required else "")
    else:
        text = "a value of the documented type"
    return text + (", or null / omitted" if nullable else "")


def node_at(root: JsonSchema, location: Sequence[str | int]) -> JsonSchema | None:
    """The schema node of the field at `location` (a pydantic loc, "body" first), if any."""
    node: JsonSchema = root
    for part in location[1:] if location and location[0] == "body" else location:
        node, _ = _resolve(node, root)
        if isinstance(part, int):
            if "items" not in node:
                return None
            node = node["items"]
        elif part in node.get("properties", {}):
            node = node["properties"][part]
        else:
            return None
    return node


def _parent(location: Sequence[str | int]) -> Sequence[str | int]:
    return location[:-1]


def explain(
    error: Mapping[str, Any], root: JsonSchema, server_limits: Mapping[str, str]
) -> dict[str, Any]:
    """One pydantic error with its message rewritten to name the field and the allowance.

    `server_limits`: extra bounds on numbers, by field path without list indices, that
    come from the server's settings rather than the schema (`{"num_samples": "<= 10000
    (this server's limit)"}`; `targets.num_samples` for every target of a batch).
    """
    location: tuple[str | int, ...] = tuple(error.get("loc", ()))
    kind = error.get("type", "")
    path = field_path(location)
    message = str(error.get("msg", "invalid"))
    if kind == "json_invalid":
        position = location[1] if len(location) > 1 else "?"
        reason = error.get("ctx", {}).get("error", "")
        message = f"not valid JSON (at character {position}: {reason})"
        allowance: str | None = describe(root, root)
        path = "body"
    elif kind == "extra_forbidden":
        parent = node_at(root, _parent(location))
        fields = ", ".join(_resolve(parent, root)[0].get("properties", {})) if parent else ""
        allowance = f"only the fields {fields}" if fields else None
        message = f"unknown field {location[-1]!r} ({message})"
    else:
        node = node_at(root, location)
        limit = server_limits.get(field_path([p for p in location if not isinstance(p, int)]))
        allowance = None if node is None else describe(node, root, limit)
    text = f"{path}: {message}" + (f"; allowed: {allowance}" if allowance else "")
    return {**error, "msg": text}
