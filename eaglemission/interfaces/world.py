"""World: the simulated ground truth the fake drivers share (simulation only).

A mission file's ``world: {type, params}`` names a world plugin; the assembly builds it first
and hands its validated ``config`` to the cameras and the vehicle (``simulation=``), which use
it if they simulate and ignore it otherwise. The mission never sees it; the core reads only
the target placement (``validate``'s geofence check) and ``campaign`` draws variants of it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np
from pydantic import BaseModel


@runtime_checkable
class World(Protocol):
    config: BaseModel
    """The validated world params (the plugin's ``Config``)."""

    @property
    def seed(self) -> int: ...

    @property
    def target_yaw_deg(self) -> float: ...

    def target_ne_m(self) -> tuple[float, float]:
        """Where the target stands, north/east metres from home."""
        ...

    def randomised_params(self, rng: np.random.RandomState,
                          route_ne_m: Sequence[tuple[float, float]]) -> dict[str, Any]:
        """The params of a random variant of this world (pure given the RNG state)."""
        ...
