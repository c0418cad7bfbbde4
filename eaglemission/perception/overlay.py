"""Overlay pictures of a detector's result, as ``eaglemission detect`` writes them: pure
functions from a frame and its :class:`~eaglemission.types.DetectionResult` (and, optionally,
the box a tracker keeps) to a BGR image.

What the picture shows:

- the saliency map as colour **only where the map is above half the threshold** (opacity
  growing with the value), so the rest of the frame keeps its own colours;
- the regions above the threshold ``T`` as white outlines;
- every detection's MBR (the best green, the others yellow) with ``#rank score`` beside it,
  and the best one's corners numbered 0-3 in the order of docs/conventions.md (clockwise on
  screen from the top-left corner, the one with the smallest ``u + v``);
- the kept target's box (a tracker's), dashed cyan, when given;
- a legend strip **below** the frame: a colour bar of the map's 0..255 scale with ``T`` marked,
  and what ``T``, the labels and the corner numbers mean.

Labels are placed outside every detection's box and the kept box (never over them); a label
with no free place beside its box is left out and listed in the legend strip. The frame keeps
its pixel coordinates in the picture: it sits at the top-left, a frame narrower than
``MIN_WIDTH_PX`` is padded on the right, and the legend is added below.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from eaglemission.types import Detection, DetectionResult

Box = tuple[float, float, float, float]
"""(u_min, v_min, u_max, v_max): pixel edges (the tracker role's box, docs/conventions.md)."""

Image = NDArray[np.uint8]

MIN_WIDTH_PX = 560
"""Narrowest picture: a narrower frame is padded on the right so the legend stays readable."""

BEST_BGR = (60, 220, 60)
OTHER_BGR = (0, 215, 255)
KEPT_BGR = (255, 230, 0)
CORNER0_BGR = (60, 60, 255)
PAD_BGR = (48, 48, 48)
LEGEND_BGR = (32, 32, 32)
TEXT_BGR = (235, 235, 235)
COLORMAP = cv2.COLORMAP_TURBO
TINT_MAX = 0.5
"""Opacity of the colour at the map's maximum (0 at half the threshold and below)."""

_FONT = cv2.FONT_HERSHEY_SIMPLEX


@dataclass(frozen=True)
class _Style:
    """Sizes scaled with the picture's width (a 640 px picture: ``unit`` 1)."""

    unit: float

    @property
    def font(self) -> float:
        return 0.45 * self.unit

    @property
    def thick(self) -> int:
        return max(1, round(self.unit))

    @property
    def gap(self) -> int:
        return max(2, round(3 * self.unit))

    @property
    def line_px(self) -> int:
        return round(19 * self.unit)


def saliency_to_uint8(saliency: NDArray[np.floating]) -> Image:
    """The map's 0..255 scale: ``round(255 x s)``, saturated; NaN and negatives give 0."""
    s = np.nan_to_num(np.asarray(saliency, np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    out: Image = np.clip(np.rint(s * np.float32(255.0)), 0, 255).astype(np.uint8)
    return out


def threshold_uint8(threshold: float) -> int:
    """The result's threshold on the map's 0..255 scale."""
    return int(round(min(max(float(threshold), 0.0), 1.0) * 255))


def tint_salient(image: Image, sal8: Image, t8: int, *, max_alpha: float = TINT_MAX) -> Image:
    """The map's colour blended over the frame where ``sal8 > t8 / 2`` only, with an opacity
    from 0 there to ``max_alpha`` at 255; elsewhere the frame's pixels are untouched."""
    floor = t8 / 2.0
    a = np.clip((sal8.astype(np.float32) - floor) / max(255.0 - floor, 1.0), 0.0, 1.0)
    a *= np.float32(max_alpha)
    heat = cv2.applyColorMap(sal8, COLORMAP).astype(np.float32)
    out = image.astype(np.float32) * (1.0 - a[..., None]) + heat * a[..., None]
    blended: Image = np.rint(out).astype(np.uint8)
    return blended


def draw_overlay(image: NDArray[np.uint8], result: DetectionResult, *,
                 kept_box: Box | None = None) -> Image:
    """The overlay picture of one frame (see the module's docstring).

    Parameters
    ----------
    image : ndarray of shape (H, W, 3) or (H, W), uint8
        The frame (BGR or grey).
    result : DetectionResult
        The detector's result on it; ``result.saliency`` is (H, W) in [0, 1] and
        ``result.threshold`` is T in [0, 1].
    kept_box : (u_min, v_min, u_max, v_max), optional
        The box a tracker keeps on this frame, pixel edges.

    Returns
    -------
    ndarray of shape (H + legend, max(W, MIN_WIDTH_PX), 3), uint8
        The frame at the top-left, at its own pixel coordinates; the legend below.
    """
    frame: Image = np.asarray(image if image.ndim == 3 else
                              cv2.cvtColor(image, cv2.COLOR_GRAY2BGR), np.uint8)
    h, w = frame.shape[:2]
    if result.saliency.shape != (h, w):
        raise ValueError(f"result.saliency: shape {result.saliency.shape} does not match the "
                         f"frame's {(h, w)}")
    sal8 = saliency_to_uint8(result.saliency)
    t8 = threshold_uint8(result.threshold)
    width = max(w, MIN_WIDTH_PX)
    style = _Style(width / 640.0)
    top = np.full((h, width, 3), PAD_BGR, np.uint8)
    top[:, :w] = tint_salient(frame, sal8, t8)
    contours, _ = cv2.findContours(((sal8 > t8) * 255).astype(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(top[:, :w], contours, -1, (255, 255, 255), 1, cv2.LINE_AA)
    taken = _boxes_mask(top.shape[:2], result.detections, kept_box, style.gap)
    for rank, det in reversed(list(enumerate(result.detections))):
        colour = BEST_BGR if rank == 0 else OTHER_BGR
        pts = np.round(det.corners_px).astype(np.int32)
        cv2.polylines(top, [pts], True, colour, 2 if rank == 0 else 1, cv2.LINE_AA)
    if kept_box is not None:
        _dashed_rect(top, kept_box, KEPT_BGR, style.thick)
    if result.detections:
        _corner_numbers(top, result.detections[0], taken, style)
    unplaced: list[str] = []
    if kept_box is not None:
        u0, v0, u1, v1 = kept_box
        if not _place_label(top, "kept", (u0, v0, u1, v1), KEPT_BGR, taken, style):
            unplaced.append("kept")
    for rank, det in enumerate(result.detections):
        text = f"#{rank} {det.score:.3g}"
        colour = BEST_BGR if rank == 0 else OTHER_BGR
        if not _place_label(top, text, _bounds(det.corners_px), colour, taken, style):
            cu, cv_ = det.center_px
            unplaced.append(f"{text} at ({cu:.0f}, {cv_:.0f})")
    legend = _legend(width, style, sal8, t8, len(result.detections), kept_box is not None,
                     unplaced)
    return np.vstack([top, legend])


def _bounds(points: NDArray[np.floating]) -> Box:
    p = np.asarray(points, np.float64).reshape(-1, 2)
    return (float(p[:, 0].min()), float(p[:, 1].min()), float(p[:, 0].max()),
            float(p[:, 1].max()))


def _boxes_mask(shape: tuple[int, int], detections: Sequence[Detection], kept_box: Box | None,
                grow_px: int) -> NDArray[np.uint8]:
    """Pixels no label may cover: every detection's MBR and the kept box, grown by
    ``grow_px`` (their outlines included)."""
    mask = np.zeros(shape, np.uint8)
    for det in detections:
        cv2.fillPoly(mask, [np.round(det.corners_px).astype(np.int32)], 255)
    if kept_box is not None:
        u0, v0, u1, v1 = kept_box
        cv2.rectangle(mask, (int(np.floor(u0)), int(np.floor(v0))),
                      (int(np.ceil(u1)), int(np.ceil(v1))), 255, -1)
    k = 2 * grow_px + 1
    grown: NDArray[np.uint8] = np.asarray(cv2.dilate(mask, np.ones((k, k), np.uint8)),
                                          np.uint8)
    return grown


def _text_size(text: str, style: _Style) -> tuple[int, int, int]:
    """Width, height above the baseline and the depth below it, px."""
    (tw, th), base = cv2.getTextSize(text, _FONT, style.font, style.thick)
    return tw, th, base


def _free(taken: NDArray[np.uint8], x0: int, y0: int, x1: int, y1: int) -> bool:
    """The rectangle lies inside the picture and covers nothing taken."""
    h, w = taken.shape
    if x0 < 0 or y0 < 0 or x1 > w or y1 > h:
        return False
    return not taken[y0:y1, x0:x1].any()


def _put_label(img: Image, text: str, x0: int, y0: int, colour: tuple[int, int, int],
               style: _Style) -> tuple[int, int, int, int]:
    """Text on a dark backing, top-left at (x0, y0); returns the rectangle painted."""
    tw, th, base = _text_size(text, style)
    pad = max(1, style.gap // 2)
    x1, y1 = x0 + tw + 2 * pad, y0 + th + base + 2 * pad
    cv2.rectangle(img, (x0, y0), (x1 - 1, y1 - 1), (20, 20, 20), -1)
    cv2.putText(img, text, (x0 + pad, y0 + pad + th), _FONT, style.font, colour, style.thick,
                cv2.LINE_AA)
    return x0, y0, x1, y1


def _place_label(img: Image, text: str, box: Box, colour: tuple[int, int, int],
                 taken: NDArray[np.uint8], style: _Style) -> bool:
    """Put ``text`` beside ``box`` (above, below, right, left; further out when those are
    taken) where it covers no box and no earlier label; a leader line joins a label placed
    further out. False when no place is free (nothing is drawn)."""
    tw, th, base = _text_size(text, style)
    pad = max(1, style.gap // 2)
    lw, lh = tw + 2 * pad, th + base + 2 * pad
    u0, v0, u1, v1 = (int(np.floor(box[0])), int(np.floor(box[1])), int(np.ceil(box[2])),
                      int(np.ceil(box[3])))
    cv = (v0 + v1) // 2
    g0 = 2 * style.gap + 1
    for step in range(6):
        g = g0 + step * lh
        for x0, y0 in ((u0, v0 - g - lh), (u1 - lw, v0 - g - lh), (u0, v1 + g),
                       (u1 - lw, v1 + g), (u1 + g, cv - lh // 2), (u0 - g - lw, cv - lh // 2)):
            if _free(taken, x0, y0, x0 + lw, y0 + lh):
                rect = _put_label(img, text, x0, y0, colour, style)
                taken[rect[1]:rect[3], rect[0]:rect[2]] = 255
                if step > 0:
                    _leader(img, rect, ((u0 + u1) / 2, (v0 + v1) / 2), colour, taken)
                return True
    return False


def _leader(img: Image, rect: tuple[int, int, int, int], towards: tuple[float, float],
            colour: tuple[int, int, int], taken: NDArray[np.uint8]) -> None:
    """A thin line from the label towards a point, stopped before the first taken pixel (a
    box's grown area or another label)."""
    lx, ly = (rect[0] + rect[2]) / 2, (rect[1] + rect[3]) / 2
    bx, by = towards
    n = int(max(abs(bx - lx), abs(by - ly)))
    last = None
    for k in range(n + 1):
        x, y = round(lx + (bx - lx) * k / max(n, 1)), round(ly + (by - ly) * k / max(n, 1))
        inside_label = rect[0] <= x < rect[2] and rect[1] <= y < rect[3]
        if inside_label:
            continue
        if not (0 <= y < taken.shape[0] and 0 <= x < taken.shape[1]) or taken[y, x]:
            break
        last = (x, y)
    if last is not None:
        start = (int(np.clip(last[0], rect[0], rect[2] - 1)),
                 int(np.clip(last[1], rect[1], rect[3] - 1)))
        cv2.line(img, start, last, colour, 1, cv2.LINE_AA)


def _corner_numbers(img: Image, det: Detection, taken: NDArray[np.uint8], style: _Style) -> None:
    """0-3 beside the best detection's corners, pushed out along the centre-to-corner
    direction until clear of every box; corner 0 in red."""
    centre = np.asarray(det.corners_px, np.float64).mean(axis=0)
    for k, corner in enumerate(np.asarray(det.corners_px, np.float64)):
        text = str(k)
        tw, th, base = _text_size(text, style)
        pad = max(1, style.gap // 2)
        lw, lh = tw + 2 * pad, th + base + 2 * pad
        d = corner - centre
        d = d / max(float(np.hypot(*d)), 1e-9)
        colour = CORNER0_BGR if k == 0 else BEST_BGR
        for r in range(style.gap, 12 * style.gap + lw + lh, max(1, style.gap // 2)):
            cx, cy = corner + d * (r + 0.5 * max(lw, lh))
            x0, y0 = int(round(cx - lw / 2)), int(round(cy - lh / 2))
            if _free(taken, x0, y0, x0 + lw, y0 + lh):
                rect = _put_label(img, text, x0, y0, colour, style)
                taken[rect[1]:rect[3], rect[0]:rect[2]] = 255
                if r > 2 * style.gap:  # pushed out: a line back towards its corner
                    _leader(img, rect, (float(corner[0]), float(corner[1])), colour, taken)
                break


def _dashed_rect(img: Image, box: Box, colour: tuple[int, int, int], thick: int) -> None:
    u0, v0, u1, v1 = (int(round(c)) for c in box)
    dash = 6
    for (a, b) in (((u0, v0), (u1, v0)), ((u1, v0), (u1, v1)), ((u1, v1), (u0, v1)),
                   ((u0, v1), (u0, v0))):
        length = max(abs(b[0] - a[0]), abs(b[1] - a[1]))
        for s in range(0, length, 2 * dash):
            e = min(s + dash, length)
            p = (a[0] + (b[0] - a[0]) * s // max(length, 1), a[1] + (b[1] - a[1]) * s // max(length, 1))
            q = (a[0] + (b[0] - a[0]) * e // max(length, 1), a[1] + (b[1] - a[1]) * e // max(length, 1))
            cv2.line(img, p, q, colour, thick, cv2.LINE_AA)


def _legend(width: int, style: _Style, sal8: Image, t8: int, n_detections: int, kept: bool,
            unplaced: Sequence[str]) -> Image:
    """The strip below the frame: colour bar with T, then one line per mark."""
    u = style.unit
    x = round(8 * u)
    line = style.line_px
    lines: list[tuple[str, str]] = [
        ("regions", f"T = {t8}/255: the detector's threshold; white outlines: regions above T"),
        ("boxes", f"{n_detections} detection(s): #rank score, best first (green), others "
                  f"yellow"),
        ("corners", "corners 0-3 of the best box: clockwise from the top-left (least u+v)")]
    if kept:
        lines.append(("kept", "dashed cyan: the target box the tracker keeps"))
    if unplaced:
        lines.append(("", "no room beside its box: " + "; ".join(unplaced)))
    key_px = round(34 * u)
    widest = max(_text_size(text, style)[0] for _, text in lines)
    if x + key_px + widest > width - x:  # shrink the legend's text to fit the width
        style = _Style(u * (width - 2 * x - key_px) / widest)
    bar_h = round(12 * u)
    tick_h = _text_size("0", style)[1] + round(10 * u)
    height = round(8 * u) + bar_h + tick_h + line * len(lines) + round(8 * u)
    strip = np.full((height, width, 3), LEGEND_BGR, np.uint8)
    # colour bar of the 0..255 scale, T marked
    bar_w = min(round(256 * u), width // 2)
    y = round(8 * u)
    ramp = np.linspace(0, 255, bar_w).round().astype(np.uint8)[None, :].repeat(bar_h, axis=0)
    strip[y:y + bar_h, x:x + bar_w] = cv2.applyColorMap(ramp, COLORMAP)
    tx = x + round(t8 / 255 * (bar_w - 1))
    cv2.line(strip, (tx, y - round(3 * u)), (tx, y + bar_h + round(2 * u)), (255, 255, 255),
             max(1, style.thick + 1))
    base_y = y + bar_h + tick_h - round(3 * u)
    for value, text in ((0, "0"), (255, "255")):
        tw = _text_size(text, style)[0]
        px = x + round(value / 255 * (bar_w - 1)) - (0 if value == 0 else tw)
        cv2.putText(strip, text, (px, base_y), _FONT, style.font, TEXT_BGR, style.thick,
                    cv2.LINE_AA)
    t_text = f"T={t8}"
    tw = _text_size(t_text, style)[0]
    lo, hi = x + _text_size("0", style)[0] + 4, x + bar_w - _text_size("255", style)[0] - 4 - tw
    cv2.putText(strip, t_text, (int(np.clip(tx - tw // 2, lo, max(lo, hi))), base_y), _FONT,
                style.font, (255, 255, 255), style.thick, cv2.LINE_AA)
    peak = int(sal8.max()) if sal8.size else 0
    caption = f"map x 255 (peak here {peak}); colour where > T/2"
    cx = x + bar_w + round(10 * u)
    fit = min(style.font, style.font * (width - x - cx) / max(_text_size(caption, style)[0], 1))
    cv2.putText(strip, caption, (cx, y + bar_h), _FONT, fit, TEXT_BGR, style.thick,
                cv2.LINE_AA)
    y = base_y + round(6 * u)
    for kind, text in lines:
        key_w = _legend_key(strip, kind, x, y, line, u)
        cv2.putText(strip, text, (x + key_w, y + line - round(6 * u)), _FONT, style.font,
                    TEXT_BGR, style.thick, cv2.LINE_AA)
        y += line
    return strip


def _legend_key(strip: Image, kind: str, x: int, y: int, line: int, u: float) -> int:
    """A small key drawn at (x, y) for one legend line; returns the width it takes."""
    s = line - round(6 * u)
    y0 = y + round(3 * u)
    if kind == "regions":
        cv2.ellipse(strip, (x + s // 2 + 2, y0 + s // 2), (s // 2, s // 3), 0, 0, 360,
                    (255, 255, 255), 1, cv2.LINE_AA)
    elif kind == "boxes":
        cv2.rectangle(strip, (x + 1, y0 + 2), (x + s // 2, y0 + s - 2), BEST_BGR, 2)
        cv2.rectangle(strip, (x + s // 2 + 3, y0 + 2), (x + s + 2, y0 + s - 2), OTHER_BGR, 1)
    elif kind == "corners":
        # a square with its corners numbered in the conventions' order
        x0, x1, a, b = x + round(7 * u), x + round(7 * u) + s, y0 + 1, y0 + s - 1
        cv2.rectangle(strip, (x0, a), (x1, b), BEST_BGR, 1)
        small = 0.32 * u
        for k, (px, py) in enumerate(((x0 - round(6 * u), a + round(4 * u)),
                                      (x1 + 1, a + round(4 * u)), (x1 + 1, b + round(2 * u)),
                                      (x0 - round(6 * u), b + round(2 * u)))):
            cv2.putText(strip, str(k), (px, py), _FONT, small,
                        CORNER0_BGR if k == 0 else BEST_BGR, 1, cv2.LINE_AA)
        return s + round(22 * u)
    elif kind == "kept":
        _dashed_rect(strip, (x + 1, y0 + 2, x + s + 2, y0 + s - 2), KEPT_BGR, 1)
    else:
        return 0
    return s + round(12 * u)
