"""One frame of the midbrain dynamic perception at one scale (Eqs. (7)-(13) of [1]), plain numpy.

This is the reference the fused numba kernel (:mod:`.kernels`) must match within 1e-5; it is
built only from the pure functions of :mod:`.equations`.

State per scale: ``g_delayed`` (the delay units ``G_d``) and ``g_prev`` (the previous frame's
response ``G``, the input the delay unit integrated over the last time step). Per frame:

1. Eq. (9) with Eq. (8): ``G_d += (G_prev - G_d) / tau``, tau from the time step in seconds
   (:func:`.equations.tau_steps`), so ``G_d(t)`` holds the responses up to frame t-1;
2. Eq. (7): ``G(t)`` from the [-1, 0, 1] derivatives of the grey image;
3. Eq. (10) as a Reichardt correlator between neighbouring pixels, x and y;
4. Eq. (11), Eq. (12) over a (2 r + 1)^2 neighbourhood, Eq. (13), minus a noise floor.

References
----------
.. [1] Eagle-eye inspired target detection (DTDMI), Sec. 2.2. DOI unknown.
"""

from __future__ import annotations

import eaglemission.detectors.dtdmi.equations_dynamic as eq
import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]


def midbrain_step_numpy(
    grey: F32, g_delayed: F32, g_prev: F32, tau: float, radius_px: int, floor: float = 0.0
) -> tuple[F32, F32, F32]:
    """Return ``(S_M, new g_delayed, new g_prev)`` for one frame (inputs not modified).

    Parameters
    ----------
    grey : ndarray of shape (H, W), float32
        Grey image of this scale (0..1).
    g_delayed, g_prev : ndarray of shape (H, W), float32
        State from the previous frame (zeros at the start: ``G_d(0) = 0``).
    tau : float
        Eqs. (8)-(9) delay parameter in steps for this frame's time step (>= 1).
    radius_px : int
        Eq. (12) neighbourhood half-size.
    floor : float
        Noise floor: the returned map is ``max(S_M - floor, 0)`` (a numerical guard: float
        rounding leaves ~1e-34 where the correlators should cancel exactly).
    """
    gd = eq.delay_update(g_delayed, eq.inhibition_output(g_prev, g_delayed, tau))  # Eqs. 8-9
    gx, gy = eq.derivative_xy(grey)
    g = eq.gradient_response(gx, gy)  # Eq. (7)
    r_x = eq.competitive_selection(g, eq.shift_neighbour(gd, 1), eq.shift_neighbour(g, 1), gd)
    r_y = eq.competitive_selection(g, eq.shift_neighbour(gd, 0), eq.shift_neighbour(g, 0), gd)
    o = eq.synthesis_2d(r_x, r_y)  # Eq. (11)
    dxx, dxy, dyy = eq.structure_tensor(o, radius_px)  # Eq. (12)
    sm = np.maximum(eq.eigenvalue_discrepancy(dxx, dxy, dyy) - floor, 0.0)  # Eq. (13)
    return sm.astype(np.float32), gd.astype(np.float32), g.astype(np.float32)
