"""The midbrain dynamic perception equations of DTDMI, Sec. 2.2 of [1] (Eqs. (7)-(14)), one
small pure function each.

Plain numpy, no state and no allocation tricks: the reference of the fused (numba) kernels of
:mod:`eaglemission.detectors.dtdmi.kernels` and of :mod:`.midbrain_step` (conventions as in
:mod:`.equations_static`).

Shapes: ``(H, W)`` maps are float32 or float64.

References
----------
.. [1] "Biological Eagle-eye Inspired Target Detection for Unmanned Aerial Vehicles Equipped
   with a Manipulator" (eagle-eye multi-camera sensor and the DTDMI saliency method), Sec. 2,
   Eqs. (1)-(15). DOI unknown.
.. [3] W. Kim, C. Kim, "Spatiotemporal Saliency Detection Using Textural Contrast and Its
   Applications", IEEE Trans. Circuits Syst. Video Technol. 24(4), 2014.
   DOI: 10.1109/TCSVT.2013.2290579.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.floating]

#: The 1-D derivative mask s = [-1, 0, 1] of Sec. 2.2 of [1] (as printed: no 1/2).
DERIVATIVE_MASK = np.array([-1.0, 0.0, 1.0])


# -- 2.2 midbrain dynamic perception -------------------------------------------------------------
def derivative_xy(grey: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Horizontal and vertical derivatives with the mask s = [-1, 0, 1] of Sec. 2.2 of [1].

    ``g_x[r, c] = I[r, c + 1] - I[r, c - 1]`` (no 1/2, as printed), same for rows; borders are
    replicated (so the derivative across the border is taken against the edge pixel).

    Parameters
    ----------
    grey : ndarray of shape (H, W)

    Returns
    -------
    gx, gy : ndarrays of shape (H, W), float32

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Sec. 2.2, before Eq. (7).
    """
    g = np.asarray(grey, np.float32)
    p = np.pad(g, 1, mode="edge")
    gx = p[1:-1, 2:] - p[1:-1, :-2]
    gy = p[2:, 1:-1] - p[:-2, 1:-1]
    return gx, gy


def gradient_response(gx: FloatArray, gy: FloatArray) -> FloatArray:
    """Gradient response ``G = sqrt(g_x^2 + g_y^2)``, Eq. (7) of [1].

    Parameters
    ----------
    gx, gy : ndarray of shape (H, W)

    Returns
    -------
    ndarray of shape (H, W)

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (7).
    """
    return np.sqrt(gx * gx + gy * gy)


def inhibition_output(g: FloatArray, g_delayed: FloatArray, tau: float) -> FloatArray:
    """Inhibition-unit output ``G_tau(t) = (G(t) - G_d(t)) / tau``, Eq. (8) of [1].

    Parameters
    ----------
    g, g_delayed : ndarray of shape (H, W)
        Response ``G(t)`` and delay-unit state ``G_d(t)``.
    tau : float
        Delay parameter in frame steps (>= 1 for a stable update). The detector derives it from
        a time constant in seconds and each frame's time step (docs/dtdmi.md).

    Returns
    -------
    ndarray of shape (H, W)

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (8).
    """
    return (g - g_delayed) / tau


def delay_update(g_delayed: FloatArray, g_tau: FloatArray) -> FloatArray:
    """Delay-unit update ``G_d(t + 1) = G_d(t) + G_tau(t)``, Eq. (9) of [1] (``G_d(0) = 0``).

    Parameters
    ----------
    g_delayed, g_tau : ndarray of shape (H, W)

    Returns
    -------
    ndarray of shape (H, W)

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (9).
    """
    return g_delayed + g_tau


def tau_steps(dt_s: float, tau_s: float, *, exact: bool = True) -> float:
    """The dimensionless ``tau`` of Eqs. (8)-(9) of [1] for a time step ``dt_s`` (seconds).

    ``exact``: ``1 / (1 - exp(-dt / tau_s))``, the exact discretisation of the first-order delay
    ``dG_d/dt = (G - G_d) / tau_s`` for an input held over the step, so the state after a given
    time is the same at any frame rate (dropped frames do not change it). Otherwise Euler's
    ``max(1, tau_s / dt)``, Eq. (8) with tau in frames as printed.

    Parameters
    ----------
    dt_s : float
        Time since the previous frame, > 0.
    tau_s : float
        Time constant of the delay unit, > 0.

    Returns
    -------
    float, >= 1

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eqs. (8)-(9).
    """
    if exact:
        return float(1.0 / -np.expm1(-dt_s / tau_s))
    return max(1.0, tau_s / dt_s)


def shift_neighbour(a: FloatArray, axis: int) -> FloatArray:
    """The next pixel along ``axis`` (column for x, row for y), border replicated.

    This is the "opposite competitive branch" of Eq. (10) of [1] as a Reichardt-style
    correlator: ``G'`` and ``G_d'`` are the response and delay state of the neighbouring pixel
    (docs/paper_choices.md).

    Parameters
    ----------
    a : ndarray of shape (H, W)
    axis : {0, 1}

    Returns
    -------
    ndarray of shape (H, W)
    """
    out = np.empty_like(a)
    if axis == 1:
        out[:, :-1] = a[:, 1:]
        out[:, -1] = a[:, -1]
    else:
        out[:-1] = a[1:]
        out[-1] = a[-1]
    return out


def competitive_selection(
    g: FloatArray, g_delayed_opp: FloatArray, g_opp: FloatArray, g_delayed: FloatArray
) -> FloatArray:
    """Competitive-selection-unit output ``R = G G_d' - G' G_d``, Eq. (10) of [1].

    Parameters
    ----------
    g : ndarray of shape (H, W)
        ``G(t)`` of this branch.
    g_delayed_opp : ndarray of shape (H, W)
        ``G_d'(t)``, the delay state of the opposite branch.
    g_opp : ndarray of shape (H, W)
        ``G'(t)``, the response of the opposite branch.
    g_delayed : ndarray of shape (H, W)
        ``G_d(t)``, this branch's delay state (before the Eq. (9) update of frame t).

    Returns
    -------
    ndarray of shape (H, W)

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (10).
    """
    return g * g_delayed_opp - g_opp * g_delayed


def synthesis_2d(r_x: FloatArray, r_y: FloatArray) -> FloatArray:
    """Two-dimensional synthesis ``O = sqrt(R_x^2 + R_y^2)``, Eq. (11) of [1].

    Parameters
    ----------
    r_x, r_y : ndarray of shape (H, W)
        Eq. (10) outputs of the horizontal and vertical correlators.

    Returns
    -------
    ndarray of shape (H, W)

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (11).
    """
    return np.sqrt(r_x * r_x + r_y * r_y)


def box_sum(a: FloatArray, radius_px: int) -> FloatArray:
    """Sum over the ``(2 r + 1)^2`` square neighbourhood ``P_i`` of every pixel (zero outside).

    Parameters
    ----------
    a : ndarray of shape (H, W)
    radius_px : int, >= 0

    Returns
    -------
    ndarray of shape (H, W), float64
    """
    a = np.asarray(a, np.float64)
    if radius_px <= 0:
        return a.copy()
    p = np.pad(a, radius_px)
    c = np.cumsum(np.cumsum(p, axis=0), axis=1)
    c = np.pad(c, ((1, 0), (1, 0)))
    k = 2 * radius_px + 1
    h, w = a.shape
    return c[k:k + h, k:k + w] - c[:h, k:k + w] - c[k:k + h, :w] + c[:h, :w]


def structure_tensor(o: FloatArray, radius_px: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Neighbourhood structure tensor of the dynamic feature, Eq. (12) of [1] (after [3]).

    ``D(i) = [[sum O_x^2, sum O_x O_y], [sum O_x O_y, sum O_y^2]]`` over the square
    neighbourhood ``P_i`` of radius ``radius_px``; ``O_x, O_y`` are the [-1, 0, 1] derivatives of
    ``O`` (unweighted sums, as printed).

    Parameters
    ----------
    o : ndarray of shape (H, W)
        Eq. (11) output.
    radius_px : int
        Neighbourhood half-size.

    Returns
    -------
    dxx, dxy, dyy : ndarrays of shape (H, W)

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (12).
    .. [3] Kim, Kim, TCSVT 2014, DOI 10.1109/TCSVT.2013.2290579.
    """
    ox, oy = derivative_xy(o)
    ox = ox.astype(np.float64)
    oy = oy.astype(np.float64)
    return box_sum(ox * ox, radius_px), box_sum(ox * oy, radius_px), box_sum(oy * oy, radius_px)


def eigenvalue_discrepancy(dxx: FloatArray, dxy: FloatArray, dyy: FloatArray) -> FloatArray:
    """``S_M = (lambda_1 - lambda_2)^2`` of the 2x2 tensor ``D``, Eq. (13) of [1].

    Closed form: for a symmetric 2x2 matrix, ``(lambda_1 - lambda_2)^2 = (a - c)^2 + 4 b^2``
    (the squared discriminant), with no square root.

    Parameters
    ----------
    dxx, dxy, dyy : ndarray of shape (H, W)
        Entries a, b, c of ``D = [[a, b], [b, c]]``.

    Returns
    -------
    ndarray of shape (H, W), >= 0

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (13).
    """
    d = dxx - dyy
    return d * d + 4.0 * dxy * dxy


def multiscale_synthesis(maps: Sequence[FloatArray]) -> FloatArray:
    """Mean of the dynamic maps of ``n`` scales, Eq. (14) of [1].

    Parameters
    ----------
    maps : sequence of n ndarrays of shape (H, W)
        ``S_M(j, r)`` brought to a common resolution.

    Returns
    -------
    ndarray of shape (H, W)

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (14).
    """
    if len(maps) == 0:
        raise ValueError("maps: need at least one scale")
    out = np.array(maps[0], dtype=np.float64)
    for m in maps[1:]:
        out += m
    return out / len(maps)
