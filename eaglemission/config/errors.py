"""pydantic validation errors as ``path: problem`` lines naming the YAML path, the bad value and
the fix (``cameras.narrow.focal_length_mm: must be > 0, got -12``). Used by the config loader
and by the registry for plugin params."""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from typing import Any

from pydantic import BaseModel, ValidationError


def _path(loc: tuple[Any, ...], prefix: str = "") -> str:
    parts: list[str] = [prefix] if prefix else []
    for item in loc:
        if isinstance(item, int):
            if parts:
                parts[-1] += f"[{item}]"
            else:
                parts.append(f"[{item}]")
        elif item in ("function-after", "function-before"):
            continue
        else:  # a key that cannot print as one plain word (empty, blank, a newline) is quoted
            text = str(item)
            parts.append(text if text and text.isprintable() and text.strip() == text
                         else repr(text))
    return ".".join(parts) or "<top level>"


def _fields_at(model: type[BaseModel] | None, loc: tuple[Any, ...]) -> list[str]:
    """Field names of the (nested) model that owns ``loc[:-1]``, for suggestions."""
    current: Any = model
    for item in loc[:-1]:
        if isinstance(item, int) or current is None:
            continue
        fields = getattr(current, "model_fields", None)
        if not fields or item not in fields:
            return []
        ann = fields[item].annotation
        current = _model_in(ann)
    fields = getattr(current, "model_fields", None)
    return list(fields) if fields else []


def _model_in(ann: Any) -> Any:
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        return ann
    for arg in getattr(ann, "__args__", ()) or ():
        found = _model_in(arg)
        if found is not None:
            return found
    return None


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _message(err: Mapping[str, Any], model: type[BaseModel] | None) -> str:
    kind = err["type"]
    ctx = err.get("ctx") or {}
    value = err.get("input")
    loc = tuple(err["loc"])
    if kind == "extra_forbidden":
        names = _fields_at(model, loc)
        close = difflib.get_close_matches(str(loc[-1]), names, n=1) if names else []
        hint = f"did you mean {close[0]!r}?" if close else (
            f"allowed keys: {', '.join(names)}" if names else "remove it")
        return f"unknown key; {hint}"
    if kind == "missing":
        return "required key is missing: add it"
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        op = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<",
              "less_than_equal": "<="}[kind]
        bound = next(iter(ctx.values()), "?")
        if isinstance(bound, float):
            bound = f"{bound:g}"
        return f"must be {op} {bound}, got {_short(value)}"
    if kind == "finite_number":
        return f"must be a finite number, got {_short(value)}"
    if kind in ("float_type", "float_parsing", "int_type", "int_parsing", "int_from_float"):
        what = "an integer" if kind.startswith("int") else "a number"
        return f"must be {what}, got {_short(value)}"
    if kind in ("bool_type", "bool_parsing"):
        return f"must be true or false, got {_short(value)}"
    if kind in ("string_type",):
        return f"must be a string, got {_short(value)}"
    if kind == "literal_error":
        return f"must be one of {ctx.get('expected', '?')}, got {_short(value)}"
    if kind in ("model_type", "dict_type", "model_attributes_type"):
        return f"must be a mapping (key: value), got {_short(value)}"
    if kind in ("list_type", "tuple_type"):
        return f"must be a list, got {_short(value)}"
    if kind in ("too_short", "too_long"):
        return f"{err['msg'].lower()}, got {_short(value)}"
    if kind == "value_error":
        return str(ctx.get("error", err["msg"]))
    return f"{err['msg']}, got {_short(value)}"


def format_validation_error(
    exc: ValidationError, *, prefix: str = "", model: type[BaseModel] | None = None
) -> list[str]:
    """One ``path: problem`` line per pydantic error."""
    lines = []
    for err in exc.errors(include_url=False):
        loc = tuple(err["loc"])
        lines.append(f"{_path(loc, prefix)}: {_message(err, model)}")
    return lines


