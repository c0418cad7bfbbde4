"""The fusion of the static and dynamic maps of DTDMI, Eq. (15) of [1]: as printed (product)
and as the field (boost) and aerial (max) presets read it.

References
----------
.. [1] "Biological Eagle-eye Inspired Target Detection for Unmanned Aerial Vehicles Equipped
   with a Manipulator" (eagle-eye multi-camera sensor and the DTDMI saliency method), Sec. 2,
   Eqs. (1)-(15). DOI unknown.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.floating]


def final_saliency(static: FloatArray, dynamic: FloatArray) -> FloatArray:
    """Final DTDMI saliency ``S = S_s x S_M`` (element-wise), Eq. (15) of [1].

    Parameters
    ----------
    static, dynamic : ndarray of shape (H, W)

    Returns
    -------
    ndarray of shape (H, W)

    References
    ----------
    .. [1] Eagle-eye inspired target detection (DTDMI), Eq. (15).
    """
    return np.asarray(static) * np.asarray(dynamic)


def boosted_saliency(static: FloatArray, dynamic: FloatArray, gain: float) -> FloatArray:
    """Eq. (15) of [1] with the dynamic map boosting instead of gating (field preset).

    ``S = S_s x (1 + gain x S_M)``: a static target is found by its colour alone (``S_M = 0``
    leaves ``S_s``), one that moves relative to its background gains from the dynamic map.
    """
    return np.asarray(static) * (1.0 + gain * np.asarray(dynamic))



def fused_saliency_max(static: FloatArray, dynamic: FloatArray, gain: float) -> FloatArray:
    """Eq. (15) of [1] as a maximum (aerial preset): ``S = max(S_s, gain x S_M)``.

    Either cue alone can nominate a region: a static object by its contrast, a moving one by the
    midbrain map, with ``gain`` putting S_M on S_s's scale. The printed product needs both.
    """
    fused: FloatArray = np.maximum(np.asarray(static), gain * np.asarray(dynamic))
    return fused
