"""Render the mission-file schema as markdown (docs/configuration.md is generated from it)."""

from __future__ import annotations

import types
import typing
from typing import Any

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

from eaglemission import registry
from eaglemission.config import models as C
from eaglemission.names import ROLES


def _type_name(ann: Any) -> str:
    origin = typing.get_origin(ann)
    args = typing.get_args(ann)
    if origin is typing.Annotated:
        inner = _type_name(args[0])
        cons = _constraints_meta(args[1:])
        return f"{inner} ({cons})" if cons else inner
    if origin in (typing.Union, types.UnionType):
        return " \\| ".join(_type_name(a) for a in args)
    if origin is typing.Literal:
        return " \\| ".join(repr(a) for a in args)
    if origin is not None:
        name = getattr(origin, "__name__", str(origin))
        if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
            return f"tuple[{_type_name(args[0])}, ...]"
        return f"{name}[{', '.join(_type_name(a) for a in args)}]"
    if ann is type(None):
        return "None"
    return getattr(ann, "__name__", str(ann))


def _constraints_meta(metadata: Any) -> str:
    parts = []
    for m in metadata:
        for attr, op in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
            v = getattr(m, attr, None)
            if v is not None:
                parts.append(f"{op} {v}")
        for sub in getattr(m, "metadata", ()) or ():
            for attr, op in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
                v = getattr(sub, attr, None)
                if v is not None:
                    parts.append(f"{op} {v}")
    return ", ".join(parts)


def _constraints(info: Any) -> str:
    return _constraints_meta(info.metadata)


def _model_of(ann: Any) -> type[BaseModel] | None:
    if isinstance(ann, type) and issubclass(ann, BaseModel):
        return ann
    for arg in typing.get_args(ann):
        m = _model_of(arg)
        if m is not None:
            return m
    return None


def _walk(lines: list[str], model: type[BaseModel], path: str, *, level: str = "##") -> None:
    doc = (model.__doc__ or "").strip().splitlines()
    lines.append(f"{level} `{path or '<top level>'}`" + (f" ({model.__name__})" if path else ""))
    lines.append("")
    if doc:
        lines.append(" ".join(d.strip() for d in doc))
        lines.append("")
    if not model.model_fields:
        lines += ["(no parameters)", ""]
        return
    lines.append("| key | type | default | constraint | meaning |")
    lines.append("|---|---|---|---|---|")
    nested = []
    for name, info in model.model_fields.items():
        if info.default is not PydanticUndefined:
            default = repr(info.default)
        elif info.default_factory is not None:
            default = "(see below)" if _model_of(info.annotation) \
                else repr(info.get_default(call_default_factory=True, validated_data={}))
        else:
            default = "**required**"
        meaning = " ".join((info.description or "").split()).replace("|", "\\|")
        lines.append(f"| `{name}` | {_type_name(info.annotation)} | {default} | "
                     f"{_constraints(info)} | {meaning} |")
        sub = _model_of(info.annotation)
        if sub is not None and sub is not C.PluginSection:
            nested.append((sub, f"{path}.{name}" if path else name))
    lines.append("")
    for sub, p in nested:
        _walk(lines, sub, p, level=level)


def _plugin_params(lines: list[str]) -> None:
    """Each shipped plugin's ``Config`` (third-party plugins document their own)."""
    for role in ROLES:
        for name, ep in sorted(registry.available(role).items()):
            if not ep.value.startswith("eaglemission."):
                continue
            _walk(lines, registry.config_model(role, name), f"{role} / {name}", level="###")


def schema_markdown() -> str:
    lines = ["# Mission file reference", "",
             "Generated from `eaglemission/config/models.py` and the shipped plugins' `Config` models by "
             "`python -m eaglemission.config.doc`;",
             "a test keeps it in sync. Units are in the key names; frames in conventions.md.", ""]
    _walk(lines, C.MissionFile, "")
    lines += ["## Plugin sections", "",
              "`{type: <entry-point name>, params: {...}}`: `params` is validated by the plugin's "
              "own `Config` model; `eaglemission plugins` lists the names. The shipped plugins' "
              "models follow, by role (`role / name`); the mission's are under "
              "`missions / approach`.", ""]
    _plugin_params(lines)
    return "\n".join(lines)


if __name__ == "__main__":
    print(schema_markdown())
