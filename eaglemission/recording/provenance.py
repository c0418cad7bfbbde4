"""What a flight was flown with: the mission file's hash and the package versions (the
mission log's ``config`` record, the MCAP recording's metadata)."""

from __future__ import annotations

import hashlib
import json
import platform
from importlib.metadata import PackageNotFoundError, version
from typing import Any

PACKAGES = ("eaglemission", "numpy", "opencv-contrib-python-headless", "scipy", "numba",
            "pydantic", "mcap", "foxglove-schemas-protobuf", "protobuf", "mavsdk", "harvesters")


def config_dict(cfg: Any) -> dict[str, Any]:
    """The validated mission file as plain JSON values."""
    out: dict[str, Any] = json.loads(json.dumps(cfg.model_dump(mode="json"), default=str))
    return out


def config_sha256(cfg: Any) -> str:
    """SHA-256 of the validated mission file (canonical JSON: sorted keys, no spaces)."""
    text = json.dumps(config_dict(cfg), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def package_versions() -> dict[str, str]:
    """Python's and the installed packages' versions (absent ones left out)."""
    out = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            pass
    return out


def config_record(cfg: Any) -> dict[str, Any]:
    """The fields of the mission log's ``config`` record."""
    return {"config": config_dict(cfg), "sha256": config_sha256(cfg),
            "versions": package_versions()}
