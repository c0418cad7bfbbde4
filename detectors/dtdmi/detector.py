"""The DTDMI detector plugin (``dtdmi``): static cluster saliency x midbrain dynamic map.

``S = S_s x S_M`` (Eq. (15) of [1]) with S_s from :mod:`.static` (Eqs. (1)-(6)) and S_M from
:mod:`.dynamic` (Eqs. (7)-(14)). Two presets:

- ``literal``: the equations as printed (1/d^2 spatial cue, raw Eq. (13) maps averaged over
  scales by Eq. (14), map = S / max S). Reproduces the paper's method; near-binary maps.
- ``default``: measured improvements (docs/paper_choices.md, "DTDMI"): per-scale normalisation
  and dynamic-range compression of S_M, Gaussian centre weight for the spatial cue, smoothing.
- ``field``: a target static on the ground seen from a moving UAV (docs/paper_choices.md,
  "field preset"): S_s in Reinhard's l-alpha-beta (chromatic distances), Eq. (2) per colour
  bin, a spatial-compactness cue instead of the centre weighting of Eqs. (3)-(5), absolute
  scale, and Eq. (15) as ``S_s x (1 + gain x S_M)`` so the dynamic map boosts, not gates.
- ``aerial``: real aerial video (docs/paper_choices.md, "aerial preset"): S_s adds to the field
  colour cue Eq. (2) read per pixel block (:func:`.equations.block_contrast_cue`), S_M aligns
  the delay units to the camera's motion (homography), Eq. (15) is ``max(S_s, gain x S_M)``,
  and the regions use the adaptive threshold.

An example image of the target (context ``appearance``, :mod:`eaglemission.detectors.appearance`)
adds its colour back-projection ``A``: ``S <- A + appearance_saliency_weight x S``.

Every preset-dependent knob is a config field whose ``None`` means "as the preset says".

References
----------
.. [1] Eagle-eye inspired target detection (DTDMI), Sec. 2. DOI unknown.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, ClassVar, Literal

import cv2
import eaglemission.detectors.dtdmi.equations as eq
import numpy as np
from eaglemission.detectors.base import DetectorConfig, SaliencyDetector, validate_image
from eaglemission.detectors.dtdmi.dynamic import DynamicParams, MidbrainDynamic, scale_shape
from eaglemission.detectors.dtdmi.static import NBINS, ClusterStatic, StaticParams, quantize_bgr
from eaglemission.detectors.regions import RegionsConfig, find_regions
from pydantic import Field, field_validator, model_validator

from eaglemission.types import Detection, DetectionResult, Frame, Saliency, TargetPrior


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
    use_dynamic: bool = True
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
    # -- appearance prior (used only when the detector gets an `appearance` image)
    appearance_prior: float = Field(0.1, gt=0, le=1, description=(
        "fraction of the frame the target is expected to cover (colour back-projection)"))
    appearance_saliency_weight: float = Field(0.25, ge=0, le=100, description=(
        "with an appearance image: S <- A + this x S (A: the colour back-projection)"))
    appearance_rank_exponent: float = Field(4.0, ge=0, le=32, description=(
        "with an appearance image: regions re-ranked by score x BC^this (BC: Bhattacharyya "
        "coefficient of the region's colour histogram and the example's); 0: off"))
    appearance_candidates: int = Field(12, ge=1, le=100, description=(
        "with an appearance image: regions re-ranked before keeping regions.max_detections"))
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
    block_luminance_weight: float = 0.3
    block_unit: float = 20.0
    block_fusion: str = "static"
    ego_motion: str = "none"


#: field preset: S_s (chromatic l-alpha-beta units) mapped to 0.5; T = 120/255 then needs
#: S > 0.89 x this (docs/paper_choices.md, "field preset").
FIELD_SATURATION = 0.3
FIELD_GAIN = 1.0

PRESETS: dict[str, Resolved] = {
    "literal": Resolved("inverse_square", "lms", False, 1.0, 1.0, 0.0, 0.0, "frame_max", 1.0),
    # default: S_M + Eq. (2) per block, tuned out of fold on DAVIS (benchmarks/tune_real.py);
    # the cluster cue of Eqs. (1)-(6) is off (colour_weight 0: S_s^0 in the grid's terms)
    "default": Resolved("inverse_square", "lms", False, 0.25, 0.5, 0.03, 0.3, "absolute", 0.5,
                        colour_weight=0.0, block_weight=0.25, block_radius_frac=0.01,
                        block_luminance_weight=0.5, block_fusion="add"),
    "field": Resolved("inverse_square", "lalphabeta", False, 0.25, 1.0, 0.001, 0.0, "absolute",
                      FIELD_SATURATION, luminance_weight=0.0, spread_sigma_frac=0.1,
                      contrast_level="bin", fusion="boost", dynamic_gain=FIELD_GAIN),
    # aerial: tuned out of fold on ../shared's UAV sequences (benchmarks/tune_real.py)
    "aerial": Resolved("inverse_square", "lalphabeta", False, 0.25, 1.0, 0.003, 0.0, "absolute",
                       3.0, luminance_weight=0.6, spread_sigma_frac=0.1, contrast_level="bin",
                       fusion="max", dynamic_gain=2.5, colour_weight=1.0, block_weight=1.0,
                       block_radius_frac=0.0055, block_luminance_weight=0.6,
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


def smooth_mapped(s: np.ndarray, sigma_px: float, out_hw: tuple[int, int],
                  to_unit: Callable[[np.ndarray, float | None, np.ndarray], None]) -> np.ndarray:
    """Gaussian smoothing (large sigma), mapped to [0, 1] by ``to_unit``, resized to ``out_hw``.

    Done on a copy reduced by ~sigma / 4 (fast); mapped there, so the bilinear upsampling
    (a convex combination) stays in [0, 1]. A map that is zero everywhere stays zero.
    """
    f = smoothing_factor(sigma_px)
    h, w = s.shape
    if f > 1:
        small = cv2.resize(s, (max(1, w // f), max(1, h // f)), interpolation=cv2.INTER_AREA)
    else:
        small = s  # small sigma (field preset): blur in place at full resolution
    return smooth_reduced(small, sigma_px / f, f == 1, out_hw, to_unit)


def smoothing_factor(sigma_px: float) -> int:
    """The reduction factor :func:`smooth_mapped` blurs at (~sigma / 4, at least 1)."""
    return max(1, int(sigma_px / 4))


def smooth_reduced(small: np.ndarray, sigma_px: float, in_place: bool, out_hw: tuple[int, int],
                   to_unit: Callable[[np.ndarray, float | None, np.ndarray], None]) -> np.ndarray:
    """The second half of :func:`smooth_mapped`: blur the reduced map ``small`` (by ``sigma_px``
    at its own resolution; in place if ``in_place``), map it, resize it to ``out_hw``."""
    small = cv2.GaussianBlur(small, (0, 0), sigma_px, dst=small if in_place else None)
    mapped = np.empty_like(small)
    to_unit(small, None, mapped)
    if mapped.shape == (out_hw[0], out_hw[1]):
        return mapped
    return cv2.resize(mapped, (out_hw[1], out_hw[0]), interpolation=cv2.INTER_LINEAR)


def lab_features(bgr: np.ndarray, luminance_weight: float) -> np.ndarray:
    """(H, W, 3) float32 CIE L*a*b* (L* in 0..100, a*, b* about -128..127; OpenCV's 8-bit
    conversion) with L* scaled by ``luminance_weight``: the block contrast cue's features."""
    lab8 = cv2.cvtColor(bgr, cv2.COLOR_BGR2Lab)
    scale = np.array([luminance_weight * 100.0 / 255.0, 1.0, 1.0], np.float32)
    offset = np.array([0.0, -128.0, -128.0], np.float32)
    return lab8.astype(np.float32) * scale + offset


def block_contrast_fast(bgr: np.ndarray, luminance_weight: float, radius_px: int,
                        surround: float) -> np.ndarray:
    """:func:`.equations.block_contrast_cue` of :func:`lab_features` in OpenCV calls only (box
    means of the 8-bit L*a*b* image straight to float, the weighted distance by
    ``cv2.transform``): the same map within float rounding (tested), ~5x faster."""
    lab8 = cv2.cvtColor(bgr, cv2.COLOR_BGR2Lab)
    r = max(1, int(radius_px))
    big = max(r + 1, int(round(surround * r)))
    centre = cv2.boxFilter(lab8, cv2.CV_32F, (2 * r + 1, 2 * r + 1),
                           borderType=cv2.BORDER_REFLECT)
    around = cv2.boxFilter(lab8, cv2.CV_32F, (2 * big + 1, 2 * big + 1),
                           borderType=cv2.BORDER_REFLECT)
    cv2.subtract(centre, around, dst=centre)
    cv2.multiply(centre, centre, dst=centre)
    wl = luminance_weight * 100.0 / 255.0
    dist = cv2.transform(centre, np.array([[wl * wl, 1.0, 1.0]], np.float32))
    return cv2.sqrt(dist.reshape(dist.shape[0], dist.shape[1]))


def appearance_rerank(dets: tuple[Detection, ...], image: np.ndarray, q: np.ndarray,
                      gamma: float, keep: int) -> tuple[Detection, ...]:
    """Detections re-ranked by ``score x BC^gamma`` (BC: Bhattacharyya coefficient of the
    region's colour histogram and the example's ``q``), the best ``keep``, that product as their
    score (:mod:`eaglemission.detectors.appearance`)."""
    from eaglemission.detectors.appearance import bhattacharyya, region_histogram

    ranked = sorted(
        ((d.score * bhattacharyya(region_histogram(image, d.corners_px), q) ** gamma, k)
         for k, d in enumerate(dets)), reverse=True)
    return tuple(replace(dets[k], score=float(s)) for s, k in ranked[:keep])


class DTDMIEngine:
    """The stateful computation (no plugin plumbing): ``saliency(bgr, timestamp_ns)``.

    Full-frame planes are preallocated per resolution (fresh arrays every frame cost thousands
    of page faults at 1280x960); with ``backend="numba"`` the per-pixel passes are the fused
    kernels of :mod:`.kernels`, otherwise plain numpy with the same results (tested, 1e-5).
    """

    def __init__(self, cfg: DTDMIConfig) -> None:
        self.cfg = cfg
        self.r = resolve(cfg)
        self.numba = cfg.backend == "numba"
        if self.numba:
            import eaglemission.detectors.dtdmi.kernels as kernels

            self._k = kernels
        self.static = ClusterStatic(StaticParams(
            clusters=cfg.clusters, colour_space=self.r.colour_space,
            spatial_weight=self.r.spatial_weight, window_s=cfg.window_s,
            kmeans_weight=cfg.kmeans_weight, backend=cfg.backend,
            luminance_weight=self.r.luminance_weight, spread_sigma_frac=self.r.spread_sigma_frac,
            contrast_level=self.r.contrast_level, spread_pool=self.r.spread_pool))
        self.dynamic = MidbrainDynamic(DynamicParams(
            scales=tuple(cfg.scales), tau_s=cfg.tau_s, tensor_radius_px=cfg.tensor_radius_px,
            ego_motion=self.r.ego_motion, ego_motion_width_px=cfg.ego_motion_width_px,
            backend=cfg.backend, floor=cfg.dynamic_floor))
        self._shape: tuple[int, int] | None = None
        self.appearance: Any = None  # AppearanceModel (detectors/appearance.py) or None
        # S_s as a weighted sum of cues, the max fusion or an appearance image: the general
        # (unstreamed) path of _general_saliency
        self.general = (self.r.block_weight > 0 or self.r.fusion == "max"
                        or self.r.colour_weight != 1.0)

    def set_appearance(self, model: Any) -> None:
        """Use an appearance model (or None) from the next frame on."""
        self.appearance = model
        self.general = self.general or model is not None
        self._shape = None  # reallocate: the general path does not pool the smoothing

    def reset(self) -> None:
        self.static.reset()
        self.dynamic.reset()

    def _allocate(self, shape: tuple[int, int]) -> None:
        h, w = shape
        self._has_full = self.cfg.scales[0] == 1.0
        n_up = min(1, len(self.cfg.scales) - (1 if self._has_full else 0))
        # colour bin per pixel: the numba kernels compute it on the fly where they paint
        self._idx = np.zeros((1, 1) if self.numba else shape, np.uint16)
        self._out = np.zeros(shape, np.float32)
        # numpy backend: the coarse scales upsampled to full resolution (numba: on the fly)
        self._ups = np.zeros((n_up, h, w) if not self.numba else (n_up, 1, 1), np.float32)
        self._no_base = np.zeros((0, 1), np.float32)
        self._no_lut = np.zeros(1, np.float32)
        # numba and no per-scale normalisation (that needs each scale's maximum first): every
        # scale is streamed into Eqs. (14)-(15) (_streamed) when the scales are the full
        # resolution plus at most two coarser ones of different sizes (the plain version sums
        # the coarse scales at the larger one's resolution; with two, that is a chain).
        coarse_hw = [scale_shape(shape, s) for s in self.cfg.scales[1:]]
        self._chain = (self.numba and not self.r.normalize_scales and self._has_full
                       and len(coarse_hw) <= 2 and len(set(coarse_hw)) == len(coarse_hw)
                       and shape not in coarse_hw)
        # streamed, no ego-motion (it aligns on the float grey), second scale exactly half:
        # its grey comes from kernels.grey_half
        # (and every further one exactly half the one before, so that dynamic.step reduces
        # it from that one, never from the 8-bit frame)
        self._half = None
        if self._chain and self.r.ego_motion == "none" and coarse_hw:
            ok, prev = True, (h, w)
            for hw in coarse_hw:
                ok = ok and prev[0] % 2 == 0 and prev[1] % 2 == 0 and \
                    hw == (prev[0] // 2, prev[1] // 2)
                prev = hw
            if ok:
                self._half = np.zeros(coarse_hw[0], np.float32)
        self._up: dict[tuple[tuple[int, int], tuple[int, int]],
                       tuple[tuple[np.ndarray, ...], np.ndarray | None]] = {}
        self._grey8 = np.zeros(shape, np.uint8)
        self._grey = np.zeros(shape, np.float32)
        self._hist = np.zeros(NBINS, np.float64)
        self._whist = np.zeros(NBINS, np.float64)
        self._mom = np.zeros((NBINS, 4), np.float64)
        self._dummy = np.zeros((1, 1), np.float32)
        rows = np.arange(h)[:, None]
        cols = np.arange(w)[None, :]
        c = self.r.centre_sigma_frac
        self._centre = (eq.gaussian_centre_weight(rows, cols, shape, c).astype(np.float32)
                        if c > 0 else self._dummy)
        # the same Gaussian as a separable product (centre = row weight x column weight)
        self._centre_row = (eq.gaussian_centre_weight(rows[:, 0], (w - 1) / 2.0, shape, c)
                            .astype(np.float32) if c > 0 else np.ones(h, np.float32))
        self._centre_col = (eq.gaussian_centre_weight((h - 1) / 2.0, cols[0], shape, c)
                            .astype(np.float32) if c > 0 else np.ones(w, np.float32))
        # Default preset (numba): Eqs. (14)-(15) go straight into the f x f block means that
        # the smoothing starts from (kernels.combine / midbrain_combine with f > 1: what
        # smooth_mapped's INTER_AREA reduction gives), so no full-resolution S plane is written.
        self._pool_f = 0
        if (self.numba and self.r.blur_sigma_frac > 0 and self.r.fusion != "boost"
                and not self.general):
            f = smoothing_factor(self.r.blur_sigma_frac * float(np.hypot(h, w)))
            if f > 1 and h % f == 0 and w % f == 0:
                self._pool_f = f
                self._pooled = np.zeros((h // f, w // f), np.float32)
        self._shape = shape

    # -- parts ----------------------------------------------------------------------------------
    def _static_lut(self, work: np.ndarray, timestamp_ns: int) -> np.ndarray:
        if self.static.field:  # field preset: compactness x per-bin contrast, absolute
            if self.numba:
                self._k.sampled_moments(work, self.static.p.sample_step_px, self._hist, self._mom)
                hist, mom = self._hist, self._mom
            else:
                self._idx[...] = quantize_bgr(work)
                hist, mom = self.static.moments(self._idx)
            lut = self.static.bin_saliency_field(hist, mom, self._shape)
        else:
            if self.numba:
                wgrid = self.static.weight_grid(self._shape)
                self._k.sampled_hist(work, self.static.p.sample_step_px, wgrid, self._hist,
                                     self._whist)
                hist, whist = self._hist, self._whist
            else:
                self._idx[...] = quantize_bgr(work)
                hist, whist = self.static.histograms(self._idx)
            lut = self.static.bin_saliency_from_hist(hist, whist, timestamp_ns)  # Eqs. (2)-(6)
        if self.r.static_exponent != 1.0:
            lut = np.power(lut, np.float32(self.r.static_exponent))
        self._frame_hist = hist  # the sampled colour counts (appearance prior)
        return lut

    def _upsampling(self, base: np.ndarray, target_hw: tuple[int, int]
                    ) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        """The plane and :func:`.kernels.linear_coeffs` (rows, columns) the numba kernels
        upsample the coarse scales' sum from, on the fly.

        OpenCV's bilinear float resize matches the plain formula for power-of-two factors
        (weights 1/4, 3/4, ...) but not for every ratio (it quantises the weights). This is
        checked once per resolution on a random plane; where it does not match within 1e-6,
        ``base`` is resized by OpenCV to a full-resolution plane first, read with identity
        coefficients (the previous, slower way).
        """
        hw = (base.shape[0], base.shape[1])
        key = (hw, target_hw)
        if key not in self._up:
            h, w = target_hw
            ys, yw = self._k.linear_coeffs(h, max(1, hw[0]))
            xs, xw = self._k.linear_coeffs(w, max(1, hw[1]))
            exact = True
            if hw[0] > 0:
                probe = np.random.RandomState(0).rand(*hw).astype(np.float32)
                ref = cv2.resize(probe, (w, h), interpolation=cv2.INTER_LINEAR)
                rows = probe[ys] * (1 - yw[:, None]) + probe[np.minimum(ys + 1, hw[0] - 1)] \
                    * yw[:, None]
                mine = rows[:, xs] * (1 - xw) + rows[:, np.minimum(xs + 1, hw[1] - 1)] * xw
                exact = float(np.abs(mine - ref).max()) <= 1e-6
            if exact:
                self._up[key] = ((ys, yw, xs, xw), None)
            else:
                ident_y = self._k.linear_coeffs(h, h)
                ident_x = self._k.linear_coeffs(w, w)
                self._up[key] = ((*ident_y, *ident_x), np.zeros((h, w), np.float32))
        coeffs, full = self._up[key]
        if full is None:
            return base, coeffs
        h, w = target_hw
        cv2.resize(base, (w, h), dst=full, interpolation=cv2.INTER_LINEAR)
        return full, coeffs

    def _compress(self, top: float) -> float:
        """Per-scale factor ``1 / max`` (default preset) or 1 (literal)."""
        if not self.r.normalize_scales:
            return 1.0
        return 1.0 / top if top > 0 else 1.0

    def _dynamic_and_product(self, work: np.ndarray, lut: np.ndarray | None,
                             timestamp_ns: int, centre: bool = True) -> float:
        """Eqs. (7)-(15) into ``self._out``; returns its maximum. ``lut`` None: S_M alone
        (Eq. (14)); ``centre`` False: no pixel-level centre weight."""
        cv2.cvtColor(work, cv2.COLOR_BGR2GRAY, dst=self._grey8)
        if self._half is not None:
            # the full scale reads the 8-bit image (kernels._response_row), the half scale is
            # its 2 x 2 block means: no full-resolution float grey plane
            self._k.grey_half(self._grey8, self._half)
            self.dynamic.step(self._grey8, timestamp_ns, defer=True, given={1: self._half})
            return self._streamed(work, lut, centre)
        np.multiply(self._grey8, np.float32(1.0 / 255.0), out=self._grey)
        if self._chain:
            self.dynamic.step(self._grey, timestamp_ns, defer=True)
            return self._streamed(work, lut, centre)
        maps = self.dynamic.step(self._grey, timestamp_ns)
        gamma = np.float32(self.r.dynamic_exponent)
        tops = self.dynamic.tops
        full = maps[0] if self._has_full else None
        coarse = maps[1:] if self._has_full else maps
        coarse_tops = tops[1:] if self._has_full else tops
        h, w = self._shape
        for k, m in enumerate(coarse):
            f = self._compress(coarse_tops[k])
            if f != 1.0:
                m *= np.float32(f)
            if gamma == 0.25:
                np.sqrt(m, out=m)
                np.sqrt(m, out=m)
            elif gamma != 1.0:
                np.power(m, gamma, out=m)
        base = self._no_base
        if coarse:
            # The coarser scales are summed at the largest coarse scale's resolution, so only
            # one plane is upsampled to full resolution (numba: on the fly, row by row).
            b = max(range(len(coarse)), key=lambda i: coarse[i].size)
            base = coarse[b]
            for k, m in enumerate(coarse):
                if k != b:
                    base += cv2.resize(m, (base.shape[1], base.shape[0]),
                                       interpolation=cv2.INTER_LINEAR)
            if not self.numba:
                cv2.resize(base, (w, h), dst=self._ups[0], interpolation=cv2.INTER_LINEAR)
        inv0 = self._compress(tops[0]) if full is not None else 1.0
        boost = self.r.fusion == "boost" and lut is not None
        use_static = lut is not None and not boost
        # with boost, the centre weight multiplies the whole S (after the boost), not S_M alone
        use_centre = self.r.centre_sigma_frac > 0 and not boost and centre
        n = len(maps)
        if self.numba:
            # self._pool_f > 1: S only as the block means the smoothing starts from
            lut_k = lut if use_static else np.zeros(1, np.float32)
            pooled = self._pooled if self._pool_f else self._dummy
            base, up = self._upsampling(base, self._shape)
            top = float(self._k.combine(
                full if full is not None else self._dummy, np.float32(inv0), float(gamma),
                full is not None, base, up, n, lut_k, work, use_static, self._centre_row,
                self._centre_col, use_centre, self._pool_f, pooled, self._out))
            if self._pool_f:
                return -1.0  # the maximum is taken after the smoothing
            return self._boost(work, lut, top) if boost else top
        acc = self._out
        acc[...] = 0.0
        if full is not None:
            x = full * np.float32(inv0)
            acc += np.sqrt(np.sqrt(x)) if gamma == 0.25 else x ** gamma
        if coarse:
            acc += self._ups[0]
        acc *= np.float32(1.0 / n)  # Eq. (14)
        if use_static:
            acc *= lut[self._idx]  # Eq. (15)
        if use_centre:
            acc *= self._centre
        if boost:
            acc[...] = eq.boosted_saliency(lut[self._idx], acc, self.r.dynamic_gain)
            if self.r.centre_sigma_frac > 0 and centre:
                acc *= self._centre
        return float(acc.max())

    def _boost(self, work: np.ndarray, lut: np.ndarray, top: float) -> float:
        """Field preset's Eq. (15), ``S_s x (1 + gain x S_M)``, on ``self._out`` (numba)."""
        top = float(self._k.boost(work, lut, float(self.r.dynamic_gain), self._out))
        if self.r.centre_sigma_frac > 0:
            np.multiply(self._out, self._centre, out=self._out)
            top = float(self._out.max())
        return top

    def _streamed(self, work: np.ndarray, lut: np.ndarray | None, centre: bool = True) -> float:
        """Eqs. (7)-(15) (numba, ``self._chain``): every scale streamed by
        :func:`.kernels.midbrain_combine`, coarsest first, each Eq. (13) row consumed as made.

        A coarse scale's kernel writes ``S_M^gamma`` plus the (already compressed) coarser
        scale upsampled to it into its ``sm`` plane -- the sum the plain version builds at the
        largest coarse scale's resolution -- and the full-resolution scale adds that sum
        upsampled, divides by the number of scales (Eq. (14)) and applies Eq. (15). Returns
        the maximum of ``self._out`` (-1 when only the block means of the smoothing are made).
        """
        gamma = float(np.float32(self.r.dynamic_exponent))
        radius = int(self.cfg.tensor_radius_px)
        floor = float(self.cfg.dynamic_floor)
        deferred = self.dynamic.deferred
        boost = self.r.fusion == "boost" and lut is not None
        use_static = lut is not None and not boost
        use_centre = self.r.centre_sigma_frac > 0 and not boost and centre
        no_lut = self._no_lut
        base = self._no_base
        for sc, grey_s, gain in sorted(deferred[1:], key=lambda d: d[0].sm.size):
            b, up = self._upsampling(base, sc.shape)
            self._k.midbrain_combine(
                grey_s, sc.g_delayed, sc.g_prev, np.float32(gain), radius, floor, sc.o, gamma, b,
                up, 1, no_lut, work, False, self._centre_row, self._centre_col, False, 0,
                self._dummy, sc.sm)
            base = sc.sm
        sc, grey_s, gain = deferred[0]
        grey_scale = 1.0 / 255.0 if grey_s.dtype == np.uint8 else 1.0
        b, up = self._upsampling(base, self._shape)
        pooled = self._pooled if self._pool_f else self._dummy
        # boost in the same pass unless a centre weight follows it (then a pass of its own)
        boost_in = boost and self.r.centre_sigma_frac == 0
        top = float(self._k.midbrain_combine(
            grey_s, sc.g_delayed, sc.g_prev, np.float32(gain), radius, floor, sc.o, gamma, b, up,
            len(deferred), lut if (use_static or boost_in) else no_lut, work, use_static,
            self._centre_row, self._centre_col, use_centre, self._pool_f, pooled, self._out,
            float(self.r.dynamic_gain) if boost_in else -1.0, grey_scale))
        if self._pool_f:
            return -1.0  # the maximum is taken after the smoothing
        return self._boost(work, lut, top) if boost and not boost_in else top

    def _general_saliency(self, work: np.ndarray, timestamp_ns: int) -> np.ndarray:
        """S of the general path into ``self._out`` (no per-pixel fusion kernel): S_s as
        ``colour_weight x`` the colour cue ``+ block_weight x`` the block contrast cue (or the
        block cue added after Eq. (15), ``block_fusion: add``), Eq. (15) as the preset's fusion
        with S_M (Eqs. (7)-(14)), then the appearance prior and the centre weight."""
        r = self.r
        out = self._out
        s: np.ndarray | None = None
        blk: np.ndarray | None = None
        hist = None
        if self.cfg.use_static:
            if r.colour_weight > 0:
                lut = self._static_lut(work, timestamp_ns)
                hist = self._frame_hist
                self._paint(work, lut, out)
                s = out.copy() if r.colour_weight == 1.0 else out * np.float32(r.colour_weight)
            if r.block_weight > 0:
                diag = float(np.hypot(*self._shape))
                radius = round(r.block_radius_frac * diag)
                if self.numba:  # the OpenCV path (numba is the fast backend's name)
                    blk = block_contrast_fast(work, r.block_luminance_weight, radius,
                                              r.block_surround)
                else:
                    blk = eq.block_contrast_cue(lab_features(work, r.block_luminance_weight),
                                                radius, r.block_surround)
                blk *= np.float32(r.block_weight / r.block_unit)
                if r.block_fusion == "static":
                    s = blk if s is None else np.add(s, blk, out=s)
                    blk = None
        if self.cfg.use_dynamic:
            self._dynamic_and_product(work, None, timestamp_ns, centre=False)  # S_M in out
            if s is None:
                s = out.copy()
            elif r.fusion == "max":
                s = eq.fused_saliency_max(s, out, r.dynamic_gain).astype(np.float32)
            elif r.fusion == "boost":
                s = eq.boosted_saliency(s, out, r.dynamic_gain).astype(np.float32)
            else:
                s = eq.final_saliency(s, out).astype(np.float32)
        if blk is not None:  # block_fusion "add": after Eq. (15)
            s = blk if s is None else np.add(s, blk, out=s)
        if s is None:
            s = np.zeros(self._shape, np.float32)
        if self.appearance is not None:
            if hist is None:
                idx = quantize_bgr(work[::2, ::2])
                hist = np.bincount(idx.ravel(), minlength=NBINS).astype(np.float64)
            a_lut = self.appearance.lut(hist)
            self._paint(work, a_lut, out)
            s = np.add(out, s * np.float32(self.cfg.appearance_saliency_weight), out=s)
        if r.centre_sigma_frac > 0:
            s *= self._centre
        out[...] = s
        return out

    def _paint(self, work: np.ndarray, lut: np.ndarray, out: np.ndarray) -> None:
        """``out = lut[bin(work)]`` (colour bins of :func:`.static.quantize_bgr`)."""
        if self.numba:
            self._k.paint_static(work, lut, self._dummy, False, out)
        else:
            np.take(lut, quantize_bgr(work), out=out)

    # -- whole frame ----------------------------------------------------------------------------
    def saliency(self, bgr: np.ndarray, timestamp_ns: int) -> np.ndarray:
        """float32 (H, W) map in [0, 1] at the resolution of ``bgr``."""
        cfg = self.cfg
        work = bgr
        if cfg.downscale > 1:
            h, w = bgr.shape[:2]
            work = cv2.resize(bgr, (max(8, w // cfg.downscale), max(8, h // cfg.downscale)),
                              interpolation=cv2.INTER_AREA)
        work = np.ascontiguousarray(work)
        shape = (work.shape[0], work.shape[1])
        if shape != self._shape:
            self._allocate(shape)
        if self.general:
            return self._finish(self._general_saliency(work, timestamp_ns), -1.0, bgr, shape)
        lut = self._static_lut(work, timestamp_ns) if cfg.use_static else None
        out = self._out
        if cfg.use_dynamic:
            top = self._dynamic_and_product(work, lut, timestamp_ns)
        else:
            assert lut is not None
            use_centre = self.r.centre_sigma_frac > 0
            if self.numba:
                top = float(self._k.paint_static(work, lut, self._centre, use_centre, out))
            else:
                np.take(lut, self._idx, out=out)
                if use_centre:
                    out *= self._centre
                top = float(out.max())
        if cfg.use_dynamic and self._pool_f:
            sigma_px = self.r.blur_sigma_frac * float(np.hypot(*shape))
            return smooth_reduced(self._pooled, sigma_px / self._pool_f, True,
                                  (bgr.shape[0], bgr.shape[1]), self._to_unit)
        return self._finish(out, top, bgr, shape)

    def _finish(self, out: np.ndarray, top: float, bgr: np.ndarray,
                shape: tuple[int, int]) -> np.ndarray:
        """Smoothing, the output scale and the resize back to the frame's resolution."""
        full_shape = (bgr.shape[0], bgr.shape[1])
        if self.r.blur_sigma_frac > 0:
            return smooth_mapped(out, self.r.blur_sigma_frac * float(np.hypot(*shape)),
                                 full_shape, self._to_unit)
        result = np.empty(shape, np.float32)
        self._to_unit(out, top if top >= 0 else None, result)
        if shape != full_shape:
            return cv2.resize(result, (full_shape[1], full_shape[0]),
                              interpolation=cv2.INTER_LINEAR)
        return result

    def _to_unit(self, s: np.ndarray, top: float | None, result: np.ndarray) -> None:
        """Map S >= 0 to [0, 1] into ``result``: per-frame max or absolute saturation."""
        if self.r.output_scale == "absolute":
            np.add(s, np.float32(self.r.saturation), out=result)
            np.divide(s, result, out=result)
            return
        top = float(s.max()) if top is None else top
        if top > 1e-30:
            np.multiply(s, np.float32(1.0 / top), out=result)
            np.minimum(result, np.float32(1.0), out=result)
        else:
            result[...] = 0.0


class DTDMIDetector(SaliencyDetector):
    """DTDMI: static cluster saliency x eagle-midbrain dynamic map (Eqs. (1)-(15) of [1])."""

    Config: ClassVar[type[DTDMIConfig]] = DTDMIConfig
    description: ClassVar[str] = (
        "DTDMI: static cluster saliency x eagle-midbrain dynamic perception (paper Sec. 2)")

    def __init__(self, config: DTDMIConfig | None = None, **context: Any) -> None:
        super().__init__(config, **context)
        self.engine = DTDMIEngine(self.config)
        if self.engine.numba:
            self._warm_up()
        if self.appearance is not None:
            from eaglemission.detectors.appearance import AppearanceModel

            self.engine.set_appearance(AppearanceModel.from_image(
                self.appearance, prior=self.config.appearance_prior))

    def detect(self, frame: Frame, prior: TargetPrior | None = None) -> DetectionResult:
        """Regions of the map; with an appearance image, the ``appearance_candidates`` best
        regions are re-ranked by ``score x BC^appearance_rank_exponent`` (their colour
        histogram against the example's, :func:`..appearance.bhattacharyya`) and
        ``regions.max_detections`` kept, with that product as their score."""
        model = self.engine.appearance
        gamma = self.config.appearance_rank_exponent
        if model is None or gamma == 0:
            return super().detect(frame, prior)
        sal = self.saliency(frame)
        cfg = self.config.regions
        wide = cfg.model_copy(update={
            "max_detections": max(cfg.max_detections, self.config.appearance_candidates)})
        dets, threshold = find_regions(sal, wide, prior, camera_id=frame.camera_id)
        kept = appearance_rerank(dets, validate_image(frame.image), model.q, gamma,
                                 cfg.max_detections)
        return DetectionResult(sal, kept, frame.timestamp_ns, frame.camera_id, frame.seq,
                               threshold)

    def _warm_up(self) -> None:
        """Compile (or load from numba's cache) every kernel now, not on the first real frame."""
        rng = np.random.RandomState(0)
        for k in range(2):
            img = rng.randint(0, 256, (32, 32, 3)).astype(np.uint8)
            self.engine.saliency(img, 1_000_000_000 + k * 33_000_000)
        self.engine.reset()

    def _reset(self) -> None:
        self.engine.reset()

    def _saliency(self, image: np.ndarray, frame: Frame) -> Saliency:
        return self.engine.saliency(image, frame.timestamp_ns)
