"""The ``synthetic`` world: procedural ground, the target box, distractors, wind and the
realism knobs that make the rendering cameras differ from their nominal models.

Its schema lives here, with the fake drivers that read it (the synthetic cameras render it,
the simulated vehicle takes its wind, the evaluator judges against its target); the mission
never sees it. ``campaign`` draws random variants of it through :meth:`randomised_params`.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Sequence
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, model_validator

from eaglemission.config import Finite, NonNegFloat, PosFloat, StrictModel

TEXTURES = ("vegetation", "soil", "snow", "grass")

WhiteBalanceGain = Annotated[float, Field(ge=0.25, le=4.0)]


class DistractorConfig(StrictModel):
    kind: Literal["box", "disc", "stripe", "moving_box"] = "box"
    north_m: Finite
    east_m: Finite
    size_m: PosFloat = 0.5
    height_m: NonNegFloat = 0.1
    color_bgr: tuple[int, int, int] = (40, 40, 200)
    velocity_ne_mps: tuple[Finite, Finite] = (0.0, 0.0)


class GroundImageConfig(StrictModel):
    """A real aerial photograph as the ground (north up, centred on home + ``offset_ne_m``,
    mirrored beyond its edge); the photos are never copied into the repository."""

    path: str = Field(description="NAME.jpg|png, nadir photo of the ground")
    m_per_px: PosFloat | None = Field(
        default=None, description="metres per pixel (default: `m_per_px` of NAME.yaml)")
    offset_ne_m: tuple[Finite, Finite] = (0.0, 0.0)
    detail: bool = Field(default=True, description="add the fine detail layer (2.5 mm up to "
                         "the photo's 2 px) at the camera's scale")

    @model_validator(mode="before")
    @classmethod
    def _check_files(cls, data: Any) -> Any:
        from pathlib import Path

        from eaglemission.lab.world.ground_images import sidecar_m_per_px

        if not isinstance(data, dict) or not isinstance(data.get("path"), str):
            return data
        p = Path(data["path"])
        if not p.is_file():
            raise ValueError(f"path: ground image {p} not found")
        if data.get("m_per_px") is None:
            data = {**data, "m_per_px": sidecar_m_per_px(p)}
        return data


class SyntheticWorldConfig(StrictModel):
    """The simulated world (ground truth). Only fake drivers and the evaluator read it."""

    seed: int = 0
    target_north_m: Finite = 20.0
    target_east_m: Finite = 5.0
    target_yaw_deg: Annotated[float, Field(ge=-180, le=180)] = 0.0
    ground_texture: Literal["vegetation", "soil", "snow", "grass"] = "vegetation"
    ground_image: GroundImageConfig | None = Field(
        default=None, description="real aerial photo as the ground (replaces ground_texture)")
    distractors: list[DistractorConfig] = Field(default_factory=list)
    light_gain: Annotated[float, Field(gt=0, le=4)] = 1.0
    noise_sigma: Annotated[float, Field(ge=0, le=50)] = 2.0
    wind_ne_mps: tuple[Finite, Finite] = (0.0, 0.0)
    mount_error_deg: Annotated[float, Field(ge=0, le=10)] = 0.0
    focal_error_fraction: Annotated[float, Field(ge=0, le=0.2)] = 0.0
    camera_time_offset_s: Annotated[float, Field(ge=0, le=0.2)] = 0.0
    frame_rate_hz: Annotated[float, Field(gt=0, le=200)] = 30.0
    # imaging effects (docs/simulation.md, "Imaging effects"); all off by default
    white_balance_gains_bgr: tuple[WhiteBalanceGain, WhiteBalanceGain, WhiteBalanceGain] = Field(
        default=(1.0, 1.0, 1.0), description="per-channel gain error on every frame (B, G, R): "
        "an auto-white-balance error or another illuminant colour")
    motion_blur: bool = Field(default=False, description="smear each frame along the image "
                              "motion of the optical-axis ground point during the exposure")
    bayer_pattern: Literal["BayerRG", "BayerBG", "BayerGR", "BayerGB"] | None = Field(
        default=None, description="mosaic each frame to this colour filter (the daA1280-54uc: "
        "BayerRG) and demosaic it as the genicam driver does")
    jpeg_quality: Annotated[int, Field(ge=1, le=100)] | None = Field(
        default=None, description="JPEG-encode and decode each frame at this quality, as a "
        "recorded or streamed frame")


class SyntheticWorld:
    """The ``synthetic`` world plugin: holds the validated world description (the renderer,
    :class:`~eaglemission.lab.world.render.SyntheticWorld`, is built from it by the
    cameras on first use)."""

    Config = SyntheticWorldConfig
    description = "procedural ground with the target box, distractors and wind (simulation)"
    imaging_keys = ("white_balance_gains_bgr", "motion_blur", "bayer_pattern", "jpeg_quality")
    """The keys :func:`imaging_draws` varies (``campaign --no-imaging-effects`` keeps them)."""

    def __init__(self, config: SyntheticWorldConfig, **_context: Any) -> None:
        self.config = config

    @property
    def seed(self) -> int:
        return self.config.seed

    def target_ne_m(self) -> tuple[float, float]:
        return (self.config.target_north_m, self.config.target_east_m)

    @property
    def target_yaw_deg(self) -> float:
        return self.config.target_yaw_deg

    def randomised_params(self, rng: np.random.RandomState,
                          route_ne_m: Sequence[tuple[float, float]]) -> dict[str, Any]:
        """A random variant of this world (pure given the RNG state): target along the route
        (35-75% of its length, +-3 m across), heading, texture, 0-2 distractors, lighting,
        wind (0-3 m/s, any direction), mount error 2 deg, focal error 3%, camera-to-telemetry
        offset 0-40 ms and the world seed; then the imaging effects of :func:`imaging_draws`
        (from an RNG of the drawn world seed, so the draws before stay as they were)."""
        route = np.array(route_ne_m, dtype=float).reshape(-1, 2)
        seg_len = np.linalg.norm(np.diff(route, axis=0), axis=1) if len(route) > 1 \
            else np.ones(1)
        s = rng.uniform(0.35, 0.75) * float(seg_len.sum())
        i = int(np.searchsorted(np.cumsum(seg_len), s)) if len(route) > 1 else 0
        i = min(i, len(route) - 2) if len(route) > 1 else 0
        a = route[i]
        b = route[i + 1] if len(route) > 1 else route[i] + np.array([1.0, 0.0])
        start = float(np.cumsum(seg_len)[i - 1]) if i > 0 else 0.0
        u = (b - a) / max(1e-9, float(np.linalg.norm(b - a)))
        side = np.array([-u[1], u[0]])
        p = a + u * (s - start) + side * rng.uniform(-3.0, 3.0)
        distractors = []
        for _ in range(int(rng.randint(0, 3))):
            for _try in range(20):
                dn = a + u * rng.uniform(0.2, 1.0) * float(seg_len.sum()) \
                    + side * rng.uniform(-6, 6)
                if np.linalg.norm(dn - p) >= 4.0:
                    break
            # draw order kept as in every campaign so far (kind, size, height, colour)
            kind = ("box", "disc", "stripe")[int(rng.randint(0, 3))]
            size_m = float(rng.uniform(0.3, 0.8))
            height_m = float(rng.uniform(0.0, 0.2))
            c = rng.randint(20, 235, size=3)
            distractors.append(DistractorConfig(
                kind=kind, north_m=float(dn[0]), east_m=float(dn[1]), size_m=size_m,
                height_m=height_m, color_bgr=(int(c[0]), int(c[1]), int(c[2]))))
        wind_speed = rng.uniform(0.0, 3.0)
        wind_dir = rng.uniform(-math.pi, math.pi)
        varied = self.config.model_copy(update={
            "seed": int(rng.randint(0, 2**31 - 1)),
            "target_north_m": float(p[0]), "target_east_m": float(p[1]),
            "target_yaw_deg": float(rng.uniform(-180.0, 180.0)),
            "ground_texture": TEXTURES[int(rng.randint(0, len(TEXTURES)))],
            "distractors": distractors,
            "light_gain": float(rng.uniform(0.7, 1.3)),
            "wind_ne_mps": (float(wind_speed * math.cos(wind_dir)),
                            float(wind_speed * math.sin(wind_dir))),
            "mount_error_deg": 2.0,
            "focal_error_fraction": 0.03,
            "camera_time_offset_s": float(rng.uniform(0.0, 0.040)),
        })
        # The imaging effects come from an RNG of the drawn world seed, not from ``rng``: the
        # draws above do not depend on them (a seed gives the same worlds with
        # ``--no-imaging-effects``).
        varied = varied.model_copy(update=imaging_draws(varied.seed))
        return varied.model_dump()


WB_TEMPERATURE_LOG_GAIN = 0.15
"""Campaign white balance: R x e^t, B x e^-t with t uniform in +-this (an auto-white-balance
error or an illuminant of another colour temperature: R/B up to x1.35 either way)."""
WB_TINT_LOG_GAIN = 0.04
"""Campaign white balance: G x e^g with g uniform in +-this (green-magenta tint)."""
JPEG_FRACTION = 0.5
"""Campaign: the share of runs whose frames go through JPEG (quality 60-95)."""


def imaging_draws(world_seed: int) -> dict[str, Any]:
    """The campaign's imaging effects of a world: motion blur and the daA1280-54uc's BayerRG
    demosaicing always (they are physical), a white-balance error, and JPEG at quality 60-95 in
    half of the runs; drawn from an RNG of ``world_seed`` alone (pure)."""
    g = np.random.RandomState(zlib.crc32(f"imaging/{int(world_seed)}".encode()))
    t = g.uniform(-WB_TEMPERATURE_LOG_GAIN, WB_TEMPERATURE_LOG_GAIN)
    tint = g.uniform(-WB_TINT_LOG_GAIN, WB_TINT_LOG_GAIN)
    jpeg = g.uniform() < JPEG_FRACTION
    quality = int(g.randint(60, 96))
    return {"white_balance_gains_bgr": (float(math.exp(-t)), float(math.exp(tint)),
                                        float(math.exp(t))),
            "motion_blur": True, "bayer_pattern": "BayerRG",
            "jpeg_quality": quality if jpeg else None}


def world_config(mission: Any) -> SyntheticWorldConfig | None:
    """The synthetic world of a mission file (``world.type: synthetic``), validated; None when
    the file has no world or another one."""
    section = getattr(mission, "world", None)
    if section is None or section.type != "synthetic":
        return None
    return SyntheticWorldConfig.model_validate(section.params)
