"""Plugin registry: entry points, one group per role, checked against the role's Protocol.

Plugins are loaded only from entry points (``eaglemission.cameras``, ``.vehicles``,
``.detectors``, ``.estimators``, ``.fitters``, ``.trackers``, ``.manipulators``, ``.missions``, ``.worlds``,
``.sections``, ``.judges``); a config can never name an import path. A plugin class declares ``Config`` (a pydantic model of its params, with defaults) and a one-line
``description``; ``load(role, name, params, **context)`` validates the params with that model
and constructs the plugin as ``cls(config=..., **context)``.
"""

from __future__ import annotations

import difflib
import inspect
from collections.abc import Mapping
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from pydantic import BaseModel, ValidationError

from eaglemission.config.errors import format_validation_error
from eaglemission.errors import ConfigError, PluginError
from eaglemission.interfaces import (
    Camera,
    Detector,
    Estimator,
    Judge,
    Manipulator,
    Mission,
    PlaneFitter,
    Section,
    Tracker,
    Vehicle,
    World,
)
from eaglemission.names import ENTRY_POINT_PREFIX, ROLES

PROTOCOLS: dict[str, type] = {
    "cameras": Camera,
    "vehicles": Vehicle,
    "detectors": Detector,
    "estimators": Estimator,
    "fitters": PlaneFitter,
    "trackers": Tracker,
    "manipulators": Manipulator,
    "missions": Mission,
    "worlds": World,
    "sections": Section,
    "judges": Judge,
}


def _check_role(role: str) -> None:
    if role not in ROLES:
        raise PluginError(f"unknown plugin role {role!r}: use one of {', '.join(ROLES)}")


def group(role: str) -> str:
    _check_role(role)
    return ENTRY_POINT_PREFIX + role


def available(role: str) -> dict[str, EntryPoint]:
    """Entry points of a role by name (nothing imported)."""
    return {ep.name: ep for ep in entry_points(group=group(role))}


def protocol_members(proto: type) -> dict[str, Any]:
    """Methods and attributes a Protocol declares (excluding dunders)."""
    members: dict[str, Any] = {}
    for klass in reversed(proto.__mro__):
        if klass in (object,) or klass.__name__ in ("Protocol", "Generic"):
            continue
        for name, value in vars(klass).items():
            if name.startswith("_"):
                continue
            if callable(value):
                members[name] = value
        for name in getattr(klass, "__annotations__", {}):
            if not name.startswith("_"):
                members.setdefault(name, None)
    return members


def conformance_problems(role: str, cls: type) -> list[str]:
    """What keeps ``cls`` from being a plugin of ``role`` (pluggy's ``_verify_hook``)."""
    proto = PROTOCOLS[role]
    problems: list[str] = []
    if not inspect.isclass(cls):
        return [f"must be a class, got {type(cls).__name__}"]
    cfg = getattr(cls, "Config", None)
    if not (inspect.isclass(cfg) and issubclass(cfg, BaseModel)):
        problems.append("must declare `Config`, a pydantic model of its params")
    if not isinstance(getattr(cls, "description", None), str):
        problems.append("must declare `description`, a one-line string")
    for name, spec in protocol_members(proto).items():
        if spec is None:
            continue  # data attribute: checked on the instance
        impl = getattr(cls, name, None)
        if impl is None or not callable(impl):
            problems.append(f"missing method `{name}`")
            continue
        want_async = inspect.iscoroutinefunction(spec)
        is_async = inspect.iscoroutinefunction(impl)
        if want_async != is_async:
            problems.append(f"`{name}` must be {'async' if want_async else 'a plain (sync)'} method")
        want = [p for p in inspect.signature(spec).parameters.values() if p.name != "self"]
        try:
            have = inspect.signature(impl).parameters
        except (TypeError, ValueError):
            continue
        accepts_kwargs = any(p.kind is p.VAR_KEYWORD for p in have.values())
        for p in want:
            if p.name not in have and not accepts_kwargs:
                problems.append(f"`{name}` lacks parameter `{p.name}`")
    return problems


@dataclass(frozen=True)
class PluginInfo:
    role: str
    name: str
    target: str
    description: str
    error: str | None = None


def _unknown(role: str, name: str) -> PluginError:
    names = sorted(available(role))
    close = difflib.get_close_matches(name, names, n=1)
    hint = f" Did you mean {close[0]!r}?" if close else ""
    listing = ", ".join(names) if names else "none installed"
    return PluginError(
        f"no {role[:-1]} plugin named {name!r}.{hint} Available: {listing}. "
        f"Third-party plugins register under the entry-point group {group(role)!r}."
    )


def get(role: str, name: str) -> type[Any]:
    """Import the named plugin class and check it against the role's Protocol."""
    _check_role(role)
    eps = available(role)
    if name not in eps:
        raise _unknown(role, name)
    ep = eps[name]
    try:
        cls: type[Any] = ep.load()
    except ImportError as exc:
        raise PluginError(f"{role[:-1]} plugin {name!r} ({ep.value}) cannot be imported: {exc}") from exc
    except Exception as exc:  # a broken third-party plugin must not crash the CLI
        raise PluginError(
            f"{role[:-1]} plugin {name!r} ({ep.value}) failed while importing: "
            f"{type(exc).__name__}: {exc}"
        ) from exc
    problems = conformance_problems(role, cls)
    if problems:
        raise PluginError(
            f"{role[:-1]} plugin {name!r} ({ep.value}) does not conform to "
            f"{PROTOCOLS[role].__name__}: " + "; ".join(problems)
        )
    return cls


def config_model(role: str, name: str) -> type[BaseModel]:
    """The plugin's params model (its ``Config``; conformance checked it is a pydantic model)."""
    model: type[BaseModel] = get(role, name).Config
    return model


def validate_params(role: str, name: str, params: Mapping[str, Any] | None, *, path: str) -> BaseModel:
    """Validate a plugin's params with its own Config model; errors carry the YAML path."""
    model = config_model(role, name)
    try:
        return model.model_validate(dict(params or {}))
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, prefix=path, model=model)) from None


def load(role: str, name: str, params: Mapping[str, Any] | BaseModel | None = None, **context: Any) -> Any:
    """Load, validate and construct a plugin: ``cls(config=cls.Config(**params), **context)``."""
    cls = get(role, name)
    if isinstance(params, BaseModel):
        if not isinstance(params, cls.Config):
            raise PluginError(f"params for {name!r} must be {cls.Config.__name__}")
        config = params
    else:
        config = validate_params(role, name, params, path=f"{role}.{name}.params")
    instance = cls(config=config, **context)
    missing = [m for m, spec in protocol_members(PROTOCOLS[role]).items()
               if spec is None and not hasattr(instance, m)]
    if missing:
        raise PluginError(f"{role[:-1]} plugin {name!r}: instance lacks attribute(s) {missing}")
    return instance


def describe(role: str) -> list[PluginInfo]:
    """Every plugin of a role with its description, or the reason it cannot load."""
    infos = []
    for name, ep in sorted(available(role).items()):
        try:
            cls = get(role, name)
            infos.append(PluginInfo(role, name, ep.value, str(cls.description)))
        except PluginError as exc:
            infos.append(PluginInfo(role, name, ep.value, "", error=str(exc)))
    return infos
