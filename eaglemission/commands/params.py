"""Command-line parameters of ``eaglemission bench`` and ``eaglemission detect``: ``KEY=VALUE``
items (dotted keys, YAML values) and ``--detectors`` / ``--params`` detector specs."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, get_args

from eaglemission import registry
from eaglemission.errors import EagleMissionError


class UsageError(EagleMissionError):
    """A command-line argument is wrong (missing folder, no frames, bad --params)."""


def parse_value(text: str) -> Any:
    """A ``--params`` value: YAML scalar/flow syntax (``3``, ``0.5``, ``true``, ``[1, 2]``)."""
    import yaml

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text


def set_dotted(target: dict[str, Any], key: str, value: Any) -> None:
    """``set_dotted(d, "regions.threshold", "otsu")`` -> ``d["regions"]["threshold"] = "otsu"``."""
    parts = key.split(".")
    node = target
    for p in parts[:-1]:
        child = node.setdefault(p, {})
        if not isinstance(child, dict):
            raise UsageError(f"--params {key}: {p!r} is already set to a value, not a section")
        node = child
    node[parts[-1]] = value


def parse_kv(items: Sequence[str], *, option: str = "--params") -> dict[str, Any]:
    """``["a=1", "regions.threshold=otsu"]`` -> nested dict."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"{option} {item!r}: write KEY=VALUE (e.g. regions.threshold=otsu)")
        set_dotted(out, key.strip(), parse_value(value.strip()))
    return out


def deep_merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in extra.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = v
    return out


APPEARANCE_SUFFIX = "+appearance"
"""A label ending in it runs the detector followed by the appearance prior."""


@dataclass(frozen=True)
class DetectorSpec:
    """A detector to run: plugin ``name``, report ``label`` (``name``, ``name@variant``, either
    with ``+appearance``); ``appearance``: the ``appearance`` section's params for the
    appearance prior after it (None: the detector alone)."""

    name: str
    label: str
    params: dict[str, Any] = field(default_factory=dict)
    appearance: dict[str, Any] | None = None

    @property
    def variant(self) -> str | None:
        return self.label.removesuffix(APPEARANCE_SUFFIX).partition("@")[2] or None


def preset_names(name: str) -> tuple[str, ...]:
    """The values a detector plugin's ``preset`` param takes (a ``Literal``), or ()."""
    try:
        cls = registry.get("detectors", name)
    except EagleMissionError:
        return ()
    preset = getattr(cls.Config, "model_fields", {}).get("preset")
    args = get_args(preset.annotation) if preset is not None else ()
    return tuple(a for a in args if isinstance(a, str))


def parse_detector_specs(detectors: str, params: Sequence[str]) -> list[DetectorSpec]:
    """``--detectors a,b@v`` and ``--params SPEC:k=v`` -> specs.

    ``name:k=v`` applies to every variant of ``name``; ``name@v:k=v`` to that variant only (and
    wins). A label ending in ``+appearance`` runs the detector followed by the appearance prior;
    its ``appearance.*`` params (e.g. ``dtdmi+appearance:appearance.prior.follow_weight=0``) are
    the ``appearance`` section's. A variant named after one of the plugin's presets sets ``preset: v`` unless its params
    set ``preset`` (``dtdmi@field`` with ``dtdmi@field:downscale=2`` is the field preset at
    downscale 2); any other variant with no params of its own sets ``preset: v`` too (the
    plugin's config then names an unknown preset), one with params of its own is a custom label.
    """
    labels = [s.strip() for s in detectors.split(",") if s.strip()]
    if not labels:
        raise UsageError("--detectors: give at least one detector name (e.g. sr,ft,mss)")
    if len(set(labels)) != len(labels):
        raise UsageError(f"--detectors: a detector is listed twice in {detectors!r}")
    per_name: dict[str, list[str]] = {}
    per_label: dict[str, list[str]] = {}
    for item in params:
        spec, sep, kv = item.partition(":")
        if not sep or "=" not in kv or "=" in spec:
            raise UsageError(f"--params {item!r}: write DETECTOR:KEY=VALUE "
                             f"(e.g. dtdmi:preset=literal or ft:regions.threshold=otsu)")
        spec = spec.strip()
        if spec not in labels and spec not in {
                lab.removesuffix(APPEARANCE_SUFFIX).partition("@")[0] for lab in labels}:
            raise UsageError(f"--params {item!r}: {spec!r} is not in --detectors {detectors!r}")
        (per_label if "@" in spec or spec.endswith(APPEARANCE_SUFFIX) else per_name).setdefault(
            spec, []).append(kv)
    specs = []
    for label in labels:
        base = label.removesuffix(APPEARANCE_SUFFIX)
        name, _, variant = base.partition("@")
        if not name:
            raise UsageError(f"--detectors: {label!r} has no plugin name before '@'")
        p = parse_kv(per_name.get(name, []))
        for key in dict.fromkeys((base, label)):  # the variant's, then the label's own
            p = deep_merge(p, parse_kv(per_label.get(key, [])))
        appearance = p.pop("appearance", {}) if base != label else None
        if appearance is not None and not isinstance(appearance, dict):
            raise UsageError(f"--params {label}:appearance=...: give its keys, e.g. "
                             f"{label}:appearance.prior.follow_weight=0")
        if variant and "preset" not in p and variant in preset_names(name):
            p = deep_merge(p, {"preset": variant})
        elif variant and label not in per_label and base not in per_label:
            cls = registry.get("detectors", name)
            if "preset" not in getattr(cls.Config, "model_fields", {}):
                raise UsageError(
                    f"--detectors {label!r}: {name!r} has no `preset` param; give the "
                    f"variant's params with --params {label}:KEY=VALUE")
            p = deep_merge(p, {"preset": variant})
        specs.append(DetectorSpec(name, label, p, appearance))
    return specs


def build_spec(spec: DetectorSpec, image: Any = None) -> Any:
    """The spec's detector, followed by the appearance prior for a ``+appearance`` label with
    ``image`` (the target's example image) as its colour model."""
    from eaglemission.perception.appearance import AppearanceConfig, TargetAppearance

    detector = registry.load("detectors", spec.name, spec.params)
    if spec.appearance is None:
        return detector
    if image is None:
        raise UsageError(f"--detectors {spec.label}: the appearance prior needs the target's "
                         f"example image: give --target-image FILE or first-frame")
    try:
        cfg = AppearanceConfig.model_validate(spec.appearance)
    except ValueError as exc:
        raise UsageError(f"--params {spec.label}:appearance.*: {exc}") from None
    return TargetAppearance(image=image, example=cfg.example).with_prior(
        detector, cfg.prior or AppearanceConfig().prior)
