"""Parameters of the DTDMI detector (``dtdmi``) and its presets (see docs/dtdmi.md).

:class:`DTDMIConfig` is the plugin's config; every preset-dependent knob is a field whose
``None`` means "as the preset says", and :func:`resolve` fills them in from :data:`PRESETS`
(a :class:`Resolved`). The presets are described in :mod:`.detector`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from eaglemission.detectors.base import DetectorConfig
from pydantic import Field, field_validator, model_validator

from eaglemission.perception.regions import RegionsConfig


class DTDMIConfig(DetectorConfig):
    """Parameters of the DTDMI detector (see docs/dtdmi.md)."""

    preset: Literal["literal", "default", "field", "aerial"] = "default"
    # -- dynamic part (Eqs. 7-14)
    tau_s: float = Field(0.1, gt=0, le=60, description="delay-unit time constant, Eqs. (8)-(9)")
    scales: tuple[float, ...] = Field((1.0, 0.5, 0.25), min_length=1, max_length=6,
                                      description="Eq. (14) scale factors, each in (0, 1]")
    tensor_radius_px: int = Field(2, ge=0, le=15, description="Eq. (12) neighbourhood half-size")
    ego_motion: Literal["none", "phase", "homography"] | None = Field(None, description=(
        "align the delay units to the camera's motion before Eq. (10); None: as the preset "
        "says (aerial: homography, the others: none)"))
    ego_motion_width_px: int = Field(320, ge=32, le=2048)
    dynamic_floor: float = Field(1e-20, ge=0, description=(
        "noise floor subtracted from Eq. (13) (grey in 0..1); removes float round-off where "
        "the correlators cancel (static scene)"))
    # -- static part (Eqs. 1-6)
    clusters: int = Field(8, ge=2, le=64, description="K of the colour clustering")
    window_s: float = Field(1.0, ge=0, le=60, description="Eq. (5) sequence window")
    kmeans_weight: Literal["count", "sqrt"] = Field("count", description=(
        "weight of a colour bin in the clustering: its pixel count, or its square root "
        "(rare colours, e.g. a small target, get a cluster of their own)"))
    use_static: bool = True
    use_dynamic: bool = Field(True, description=(
        "the dynamic part (Eqs. (7)-(14)); off, the map is the static part alone (a target "
        "static on the ground moves in the image as the ground does: docs/detectors.md)"))
    # -- preset-dependent (None: as the preset says)
    spatial_weight: Literal["inverse_square", "gaussian"] | None = None
    colour_space: Literal["lms", "log_lms", "lalphabeta"] | None = None
    luminance_weight: float | None = Field(None, ge=0, le=1, description=(
        "weight of l (log luminance) in lalphabeta distances; 0: chromatic contrast only"))
    spread_sigma_frac: float | None = Field(None, ge=0, le=1, description=(
        "> 0: spatial-compactness cue (spread / image diagonal at exp(-1)) instead of the "
        "Eqs. (3)-(5) centre weighting, absolute contrast (field preset); 0: Eqs. (3)-(5)"))
    contrast_level: Literal["bin", "cluster"] | None = Field(None, description=(
        "with spread_sigma_frac > 0: Eq. (2) per colour bin against the clusters, or per "
        "cluster as printed"))
    spread_pool: bool | None = Field(None, description=(
        "distribution cue: pool each colour bin with its 26 neighbouring bins"))
    fusion: Literal["product", "boost", "max"] | None = Field(None, description=(
        "Eq. (15): product S_s x S_M (as printed), boost S_s x (1 + dynamic_gain x S_M) or max "
        "max(S_s, dynamic_gain x S_M)"))
    dynamic_gain: float | None = Field(None, ge=0, le=100, description="gain of S_M in boost/max")
    colour_weight: float | None = Field(None, ge=0, le=100, description=(
        "weight of the colour cue (Eqs. (2)-(6) as the preset computes them) in S_s"))
    block_weight: float | None = Field(None, ge=0, le=100, description=(
        "weight of the block contrast cue (Eq. (2) per pixel block) in S_s; 0: off"))
    block_radius_frac: float | None = Field(None, gt=0, le=0.2, description=(
        "block contrast: half-size of the centre block, fraction of the image diagonal"))
    block_surround: float | None = Field(None, gt=1, le=20, description=(
        "block contrast: half-size of the surrounding block / that of the centre block"))
    block_luminance_weight: float | None = Field(None, ge=0, le=1, description=(
        "block contrast: weight of L* against a*, b* (CIE L*a*b*)"))
    block_unit: float | None = Field(None, gt=0, description=(
        "block contrast: L*a*b* distance that counts as 1 in S_s"))
    block_downscale: int | None = Field(None, ge=1, le=8, description=(
        "block contrast: computed on the processing-resolution frame reduced by this (area "
        "average; the blocks keep their size relative to the diagonal) and upsampled "
        "(bilinear); None: as the preset says (aerial: 2, the others: 1)"))
    block_fusion: Literal["static", "add"] | None = Field(None, description=(
        "block contrast: part of S_s before Eq. (15) (static), or added to S after it (add)"))
    normalize_scales: bool | None = None
    dynamic_exponent: float | None = Field(None, gt=0, le=1)
    static_exponent: float | None = Field(None, ge=0, le=4)
    blur_sigma_frac: float | None = Field(None, ge=0, le=0.2)
    centre_sigma_frac: float | None = Field(None, ge=0, le=10, description=(
        "pixel-level centre weight (Eq. (3) as a Gaussian, not averaged over clusters); 0: off"))
    output_scale: Literal["frame_max", "absolute"] | None = Field(None, description=(
        "frame_max: S / max S per frame (the paper: some pixel always reaches 1); absolute: "
        "S / (S + saturation), so 'no target' stays dark"))
    saturation: float | None = Field(None, gt=0, description=(
        "S that maps to 0.5 with output_scale=absolute (T = 120/255 needs S > 0.89 x this)"))
    colour_propagation: float | None = Field(None, ge=0, le=1, description=(
        "S <- (1 - this) S + this x (the mean of S over the pixels of each pixel's colour bin); "
        "0: off; None: as the preset says"))
    # -- speed
    downscale: int = Field(1, ge=1, le=8, description="process at 1/downscale resolution")
    backend: Literal["numba", "numpy"] = "numba"

    @model_validator(mode="before")
    @classmethod
    def _preset_regions(cls, data: Any) -> Any:
        """The regions default of the preset, with the given ``regions`` keys on top."""
        if not isinstance(data, dict):
            return data
        preset = data.get("preset", "default")
        base = PRESET_REGIONS.get(preset) if isinstance(preset, str) else None
        given = data.get("regions")
        if base is None or isinstance(given, RegionsConfig):
            return data
        if given is not None and not isinstance(given, dict):
            return data  # let the field's own validation report it
        return {**data, "regions": {**base, **(given or {})}}

    @field_validator("scales")
    @classmethod
    def _scales_in_unit_interval(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        for s in v:
            if not 0 < s <= 1:
                raise ValueError(f"each scale must be in (0, 1] (1 = processing resolution), "
                                 f"got {s}")
        return v


@dataclass(frozen=True)
class Resolved:
    spatial_weight: str
    colour_space: str
    normalize_scales: bool
    dynamic_exponent: float
    static_exponent: float
    blur_sigma_frac: float
    centre_sigma_frac: float
    output_scale: str
    saturation: float
    luminance_weight: float = 1.0
    spread_sigma_frac: float = 0.0
    contrast_level: str = "bin"
    spread_pool: bool = True
    fusion: str = "product"
    dynamic_gain: float = 0.0
    colour_weight: float = 1.0
    block_weight: float = 0.0
    block_radius_frac: float = 0.0055
    block_surround: float = 3.0
    block_downscale: int = 1
    block_luminance_weight: float = 0.3
    block_unit: float = 20.0
    block_fusion: str = "static"
    ego_motion: str = "none"
    colour_propagation: float = 0.0


#: field preset: S_s (chromatic l-alpha-beta units) mapped to 0.5; T = 120/255 then needs
#: S > 0.89 x this (docs/paper_choices.md, "field preset").
FIELD_SATURATION = 0.3
FIELD_GAIN = 1.0

PRESETS: dict[str, Resolved] = {
    "literal": Resolved("inverse_square", "lms", False, 1.0, 1.0, 0.0, 0.0, "frame_max", 1.0),
    # default: S_M + Eq. (2) per block + colour propagation, tuned out of fold on DAVIS
    # (benchmarks/tune_real.py); the cluster cue of Eqs. (1)-(6) is off (colour_weight 0: S_s^0
    # in the grid's terms)
    "default": Resolved("inverse_square", "lms", False, 0.25, 0.5, 0.02, 0.25, "absolute", 0.5,
                        colour_weight=0.0, block_weight=0.25, block_radius_frac=0.01,
                        block_luminance_weight=0.5, block_fusion="add", colour_propagation=0.5),
    "field": Resolved("inverse_square", "lalphabeta", False, 0.25, 1.0, 0.001, 0.0, "absolute",
                      FIELD_SATURATION, luminance_weight=0.0, spread_sigma_frac=0.1,
                      contrast_level="bin", fusion="boost", dynamic_gain=FIELD_GAIN),
    # aerial: tuned out of fold on real UAV sequences (benchmarks/tune_real.py)
    "aerial": Resolved("inverse_square", "lalphabeta", False, 0.25, 1.0, 0.003, 0.0, "absolute",
                       3.0, luminance_weight=0.6, spread_sigma_frac=0.1, contrast_level="bin",
                       fusion="max", dynamic_gain=2.5, colour_weight=1.0, block_weight=1.0,
                       block_radius_frac=0.0055, block_luminance_weight=0.6, block_downscale=2,
                       ego_motion="homography"),
}

#: Each preset's ``regions`` defaults (given keys override them; regions.py has the meaning).
#: ``literal`` and ``field`` keep the paper's fixed T = 120; ``default`` and ``aerial`` use the
#: adaptive threshold (docs/paper_choices.md, "Regions and evaluation").
PRESET_REGIONS: dict[str, dict[str, Any]] = {
    "literal": {},
    "field": {},
    "default": {"threshold": "adaptive", "adaptive_floor": 60, "peak_fraction": 0.5},
    "aerial": {"threshold": "adaptive", "adaptive_floor": 20, "peak_fraction": 0.8,
               "max_aspect": 5.0},
}


def resolve(cfg: DTDMIConfig) -> Resolved:
    """Preset values overridden by the explicitly set fields."""
    base = PRESETS[cfg.preset]
    vals = {k: getattr(cfg, k) if getattr(cfg, k) is not None else getattr(base, k)
            for k in Resolved.__dataclass_fields__}
    return Resolved(**vals)
