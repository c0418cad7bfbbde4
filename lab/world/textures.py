"""Procedural ground textures for the synthetic world, generated deterministically from a seed.

The ground is the product of two layers (docs/simulation.md, "Synthetic world"):

* a **base** texture: unique (non-repeating) BGR colour over the whole world extent at
  ``texel_m`` (5 cm by default), holding every structure larger than ~10 cm (patches of soil,
  bushes, snow drifts, mowing stripes);
* a **detail** texture: a periodic single-channel luminance modulation (mean 128 = x1.0) at
  2.5 mm per texel, holding only structures finer than ~10 cm (leaves, grass blades, grains,
  snow crust). Being band-limited, it fades to a flat 1.0 at the levels where the base texture
  takes over, so switching it off for far bands leaves no seam.

Both come with mip pyramids (2x2 box averages, which keep the detail tile periodic).
Textures are cached in-process by their parameters (``functools.lru_cache``, 3 worlds) and on
disk as ``.npy`` files (``$EAGLEMISSION_TEXTURE_CACHE``, default
``$XDG_CACHE_HOME/eaglemission/textures`` or ``~/.cache/eaglemission/textures``; set it to
``off`` to disable), so a new process loads a 200 m world in tens of milliseconds instead of
generating it in seconds. Files are written atomically and keyed by every parameter and
:data:`TEXTURE_VERSION`.
"""

from __future__ import annotations

import functools
import importlib
import logging
import math
import os
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

log = logging.getLogger(__name__)


def _scipy_fft() -> ModuleType:
    """``scipy.fft`` (scipy ships no type stubs: imported as a module object)."""
    return importlib.import_module("scipy.fft")

TEXTURE_VERSION = 1  # bump when the generators change: invalidates the disk cache

TextureKind = Literal["vegetation", "soil", "snow", "grass"]
KINDS: tuple[str, ...] = ("vegetation", "soil", "snow", "grass")

F32 = NDArray[np.float32]


def _rng(seed: int, *salt: str) -> np.random.RandomState:
    """A RandomState derived from the seed and a salt (stable across runs, unlike ``hash``)."""
    h = zlib.crc32(("/".join(salt)).encode()) ^ (int(seed) * 2654435761 & 0xFFFFFFFF)
    return np.random.RandomState(h & 0xFFFFFFFF)


# ---------------------------------------------------------------------------------------------
# Noise
# ---------------------------------------------------------------------------------------------
def value_noise(shape: tuple[int, int], cell_px: float, rng: np.random.RandomState) -> F32:
    """Smooth value noise of unit variance-ish: a random grid of ``cell_px`` spacing resized
    (bicubic) to ``shape``. Not periodic."""
    h, w = shape
    gh = max(2, int(math.ceil(h / cell_px)) + 2)
    gw = max(2, int(math.ceil(w / cell_px)) + 2)
    grid = rng.standard_normal((gh, gw)).astype(np.float32)
    # Map grid so that cell spacing is cell_px: resize the (gh-1)*cell region to the image.
    big = cv2.resize(grid, (int(round((gw - 1) * cell_px)) + 1, int(round((gh - 1) * cell_px)) + 1),
                     interpolation=cv2.INTER_CUBIC)
    return np.ascontiguousarray(big[:h, :w])


def fbm(shape: tuple[int, int], cells_px: list[float], rng: np.random.RandomState,
        gain: float = 0.6) -> F32:
    """Fractal sum of value-noise octaves (largest cell first), normalised to std 1."""
    acc = np.zeros(shape, np.float32)
    amp = 1.0
    for cell in cells_px:
        if cell < 1.0:
            break
        acc += np.float32(amp) * value_noise(shape, cell, rng)
        amp *= gain
    s = float(acc.std()) or 1.0
    acc *= np.float32(1.0 / s)
    return acc


def periodic_bandpass_noise(size: int, min_wavelength_px: float, max_wavelength_px: float,
                            rng: np.random.RandomState, *, anisotropy: float = 1.0,
                            angle_rad: float = 0.0) -> F32:
    """Periodic (tileable) noise with wavelengths in ``[min, max]`` px, built in the Fourier
    domain, normalised to zero mean and std 1. ``anisotropy`` > 1 stretches it along
    ``angle_rad`` (grass blades)."""
    white = rng.standard_normal((size, size)).astype(np.float32)
    spec = _scipy_fft().rfft2(white)  # complex64 for float32 input
    fy = np.fft.fftfreq(size).astype(np.float32)[:, None]
    fx = np.fft.rfftfreq(size).astype(np.float32)[None, :]
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    a = fx * c + fy * s
    b = -fx * s + fy * c
    f = np.sqrt((a / anisotropy) ** 2 + (b * 1.0) ** 2)
    lo, hi = 1.0 / max_wavelength_px, 1.0 / min_wavelength_px
    # Smooth band (pink-ish inside the band, soft edges).
    band = np.clip((f - lo * 0.7) / (lo * 0.3 + 1e-9), 0, 1) * np.clip((hi - f) / (hi * 0.3), 0, 1)
    amp = band / np.maximum(f, lo) ** 0.5
    out = np.asarray(_scipy_fft().irfft2(spec * amp.astype(np.float32), s=(size, size)),
                     dtype=np.float32)
    out -= out.mean()
    out /= float(out.std()) or 1.0
    return out


def _smoothstep(x: F32, lo: float, hi: float) -> F32:
    t = np.clip((x - lo) / (hi - lo), 0.0, 1.0)
    return np.asarray(t * t * (3.0 - 2.0 * t), dtype=np.float32)


def _mix(a: F32, b: F32, t: F32) -> F32:
    return a + (b - a) * t[..., None]


def _colour_field(shape: tuple[int, int], bgr: tuple[float, float, float]) -> F32:
    return np.broadcast_to(np.asarray(bgr, np.float32), (*shape, 3))


# ---------------------------------------------------------------------------------------------
# Base textures (unique, colour)
# ---------------------------------------------------------------------------------------------
def _cells(texel_m: float, metres: list[float]) -> list[float]:
    return [m / texel_m for m in metres]


def base_texture(kind: str, size_px: int, texel_m: float, seed: int) -> NDArray[np.uint8]:
    """A ``size_px`` x ``size_px`` BGR texture of the ground at ``texel_m`` per texel."""
    if kind not in KINDS:
        raise ValueError(f"ground_texture: must be one of {KINDS}, got {kind!r}")
    rng = _rng(seed, "base", kind)
    shape = (size_px, size_px)
    large = fbm(shape, _cells(texel_m, [24.0, 12.0, 6.0]), rng)  # patches
    mid = fbm(shape, _cells(texel_m, [3.0, 1.5, 0.75]), rng)  # bushes, drifts
    small = fbm(shape, _cells(texel_m, [0.4, 0.2, 0.1]), rng, gain=0.8)  # clumps, stones
    out = np.empty((size_px, size_px, 3), np.uint8)
    cols_m = np.arange(size_px, dtype=np.float32) * np.float32(texel_m)
    chunk = 256  # rows at a time: keeps the float temporaries small
    for r0 in range(0, size_px, chunk):
        r1 = min(size_px, r0 + chunk)
        img = _colourise(kind, large[r0:r1], mid[r0:r1], small[r0:r1], cols_m)
        np.clip(img, 0, 255, out=img)
        out[r0:r1] = img
    return out


def _colourise(kind: str, large: F32, mid: F32, small: F32, cols_m: F32) -> F32:
    """BGR float colours of a block of texels from its noise fields."""
    shape = large.shape
    if kind == "vegetation":
        soil = _colour_field(shape, (55, 85, 110))
        dark = _colour_field(shape, (30, 62, 38))
        light = _colour_field(shape, (55, 118, 82))
        foliage = _mix(dark, light, _smoothstep(mid + 0.4 * small, -1.2, 1.2))
        img = _mix(foliage, soil, _smoothstep(large + 0.3 * mid, 0.7, 1.3))
        img *= (1.0 + 0.12 * small)[..., None]
    elif kind == "soil":
        dry = _colour_field(shape, (95, 125, 150))
        wet = _colour_field(shape, (45, 68, 92))
        img = _mix(wet, dry, _smoothstep(large + 0.5 * mid, -1.5, 1.5))
        stones = _smoothstep(small, 1.8, 2.4)
        img = _mix(img, _colour_field(shape, (150, 158, 165)), stones)
        img *= (1.0 + 0.08 * small)[..., None]
    elif kind == "snow":
        white = _colour_field(shape, (242, 240, 236))
        shade = _colour_field(shape, (215, 198, 185))
        img = _mix(white, shade, _smoothstep(mid + 0.3 * large, 0.0, 2.5))
        rocks = _smoothstep(large + 0.4 * small, 2.0, 2.3)
        img = _mix(img, _colour_field(shape, (70, 72, 78)), rocks)
        img *= (1.0 + 0.03 * small)[..., None]
    else:  # grass
        green = _colour_field(shape, (45, 135, 75))
        dark = _colour_field(shape, (35, 95, 55))
        yellow = _colour_field(shape, (70, 160, 160))
        img = _mix(green, dark, _smoothstep(mid, -1.5, 1.5))
        img = _mix(img, yellow, _smoothstep(large + 0.3 * small, 1.0, 2.0))
        # mowing stripes, 1.5 m wide, along north
        stripe = 0.06 * np.sign(np.sin(cols_m * math.pi / 1.5)).astype(np.float32)
        img *= (1.0 + stripe[None, :, None] + 0.08 * small[..., None])
    return img


# ---------------------------------------------------------------------------------------------
# Detail textures (periodic, luminance modulation, mean 128)
# ---------------------------------------------------------------------------------------------
def detail_texture(kind: str, size_px: int, texel_m: float, seed: int) -> NDArray[np.uint8]:
    """Periodic single-channel modulation, value/128 = brightness factor, wavelengths from
    2 texels up to ~10 cm only."""
    if kind not in KINDS:
        raise ValueError(f"ground_texture: must be one of {KINDS}, got {kind!r}")
    rng = _rng(seed, "detail", kind)
    max_wl = 0.10 / texel_m
    fine = periodic_bandpass_noise(size_px, 2.0, max_wl * 0.3, rng)
    coarse = periodic_bandpass_noise(size_px, max_wl * 0.2, max_wl, rng)
    if kind == "vegetation":  # leaves: blobby, high contrast, dark gaps
        leaves = _smoothstep(coarse + 0.5 * fine, -0.6, 0.8)
        m = 0.55 + 0.75 * leaves + 0.10 * fine
    elif kind == "grass":  # blades: strongly anisotropic strokes, several orientations
        blades = np.zeros((size_px, size_px), np.float32)
        for k in range(3):
            blades += periodic_bandpass_noise(size_px, 2.0, max_wl * 0.5, rng, anisotropy=6.0,
                                              angle_rad=rng.uniform(0, math.pi) + k)
        m = 1.0 + 0.18 * blades / 1.7 + 0.12 * coarse
    elif kind == "soil":  # grains and clods
        m = 1.0 + 0.16 * fine + 0.12 * coarse + 0.25 * _smoothstep(fine, 2.0, 2.6)
    else:  # snow: smooth crust with faint sparkle
        m = 1.0 + 0.025 * coarse + 0.02 * fine + 0.12 * _smoothstep(fine, 2.6, 3.2)
    return np.ascontiguousarray(np.clip(m * 128.0, 0, 255), dtype=np.uint8)


# ---------------------------------------------------------------------------------------------
# Pyramids
# ---------------------------------------------------------------------------------------------
def mip_pyramid(img: NDArray[np.uint8], min_size_px: int = 32) -> list[NDArray[np.uint8]]:
    """Levels 0..n, each a 2x2 box average of the previous (keeps periodic textures periodic
    when the size is a power of two)."""
    levels = [img]
    while min(levels[-1].shape[:2]) >= 2 * min_size_px:
        prev = levels[-1]
        h, w = prev.shape[0] // 2, prev.shape[1] // 2
        levels.append(np.asarray(cv2.resize(prev[: 2 * h, : 2 * w], (w, h),
                                            interpolation=cv2.INTER_AREA), dtype=np.uint8))
    return levels


@dataclass(frozen=True)
class GroundTextures:
    """Base pyramid (BGR) + detail pyramid (periodic, single channel, pre-tiled).

    ``base[L]`` has texel ``base_texel_m * 2**L``; texel centre ``(col, row)`` of level L lies
    at ``east = origin_east_m + (col + 0.5) * texel``, ``north = origin_north_m - (row + 0.5)
    * texel`` (row 0 is the northern edge). ``detail_tiled[L]`` repeats the period
    ``detail_period_m`` several times so a warp needs no wrap-around border.
    """

    kind: str
    base: tuple[NDArray[np.uint8], ...]
    base_texel_m: float
    origin_north_m: float
    origin_east_m: float
    base_mean_bgr: tuple[float, float, float]
    detail_tiled: tuple[NDArray[np.uint8], ...]
    detail_texel_m: float
    detail_period_px: int  # at level 0
    border_mode: int = cv2.BORDER_CONSTANT  # beyond the base: its mean colour, or mirrored
    fade_extent_m: float | None = None  # side of the square the edge fade acts on

    @property
    def extent_m(self) -> float:
        """Side of the square around home whose outer 30 % fades to the mean colour."""
        if self.fade_extent_m is not None:
            return float(self.fade_extent_m)
        return float(self.base[0].shape[0] * self.base_texel_m)

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in self.base) + sum(a.nbytes for a in self.detail_tiled)


def cache_dir() -> Path | None:
    """The on-disk texture cache folder, or None when disabled."""
    env = os.environ.get("EAGLEMISSION_TEXTURE_CACHE")
    if env is not None:
        return None if env.strip().lower() in ("", "off", "0", "none") else Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    root = Path(xdg) if xdg else Path.home() / ".cache"
    return root / "eaglemission" / "textures"


def cached_texture(name: str, make: Callable[[], NDArray[np.uint8]]) -> NDArray[np.uint8]:
    """The texture ``name`` from the disk cache (:func:`cache_dir`), else ``make()``
    stored there (best effort)."""
    folder = cache_dir()
    path = folder / f"{name}.npy" if folder is not None else None
    if path is not None and path.is_file():
        try:
            arr = np.load(path, allow_pickle=False)
            if arr.dtype == np.uint8:
                os.utime(path)  # least-recently-used pruning goes by mtime
                return np.ascontiguousarray(arr)
        except (OSError, ValueError) as exc:
            log.warning("texture cache: cannot read %s (%s): regenerating", path, exc)
    arr = make()
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npy")
            np.save(tmp, arr, allow_pickle=False)
            os.replace(tmp, path)
            _prune(path.parent, keep=path)
        except OSError as exc:
            log.info("texture cache: cannot write %s (%s)", path, exc)
    return arr


def _prune(folder: Path, *, keep: Path) -> None:
    """Delete the least recently used cache files beyond ``$EAGLEMISSION_TEXTURE_CACHE_MB``
    (default 1024 MB)."""
    try:
        limit = float(os.environ.get("EAGLEMISSION_TEXTURE_CACHE_MB", "1024")) * 1e6
    except ValueError:
        limit = 1024e6
    files = sorted(folder.glob("v*_*.npy"), key=lambda f: f.stat().st_mtime, reverse=True)
    total = 0
    for f in files:
        total += f.stat().st_size
        if total > limit and f != keep:
            f.unlink(missing_ok=True)


def tiled_detail_levels(detail: NDArray[np.uint8], detail_texel_m: float, base_texel_m: float,
                        tiled_size_px: int) -> list[NDArray[np.uint8]]:
    """The detail texture's levels (halved each time) whose texel stays finer than the base
    texel (coarser ones are ~flat), each tiled to about ``tiled_size_px``, read-only."""
    tiled: list[NDArray[np.uint8]] = []
    lvl = detail
    while detail_texel_m * 2 ** len(tiled) < base_texel_m and lvl.shape[0] >= 8:
        reps = max(1, int(math.ceil(tiled_size_px / lvl.shape[0])))
        t = np.tile(lvl, (reps, reps))
        t.flags.writeable = False
        tiled.append(t)
        lvl = np.asarray(cv2.resize(lvl, (lvl.shape[1] // 2, lvl.shape[0] // 2),
                                    interpolation=cv2.INTER_AREA), dtype=np.uint8)
    return tiled


@functools.lru_cache(maxsize=3)
def ground_textures(kind: str, seed: int, extent_m: float, base_texel_m: float = 0.05,
                    detail_texel_m: float = 0.0025, detail_size_px: int = 2048,
                    tiled_size_px: int = 4096) -> GroundTextures:
    """Build (or fetch from the in-process cache) the textures of a world square of side
    ``extent_m`` centred on home."""
    size = int(math.ceil(extent_m / base_texel_m))
    tag = f"v{TEXTURE_VERSION}_{kind}_s{seed}"
    base = cached_texture(f"{tag}_base_{size}_{base_texel_m:g}",
                   lambda: base_texture(kind, size, base_texel_m, seed))
    base_levels = mip_pyramid(base, 16)
    for a in base_levels:
        a.flags.writeable = False
    detail = cached_texture(f"{tag}_detail_{detail_size_px}_{detail_texel_m:g}",
                     lambda: detail_texture(kind, detail_size_px, detail_texel_m, seed))
    tiled = tiled_detail_levels(detail, detail_texel_m, base_texel_m, tiled_size_px)
    mean = tuple(float(v) for v in base_levels[-1].reshape(-1, 3).mean(axis=0))
    half = size * base_texel_m / 2.0
    return GroundTextures(kind, tuple(base_levels), base_texel_m, half, -half,
                          (mean[0], mean[1], mean[2]), tuple(tiled), detail_texel_m,
                          detail_size_px)
