"""The DTDMI saliency equations (1)-(15) of [1], one small pure function each, gathered in one
namespace (``eq.<name>``) from the modules of the paper's sections:

- :mod:`.equations_static`: Sec. 2.1, Eqs. (1)-(6), and the static cues of the field and aerial
  presets;
- :mod:`.equations_dynamic`: Sec. 2.2, Eqs. (7)-(14);
- :mod:`.equations_fusion`: Eq. (15) and the presets' readings of it.

Plain numpy, no state and no allocation tricks: the reference the fused (numba) kernels of
:mod:`eaglemission.detectors.dtdmi.kernels` are tested against, and what the ``literal`` preset
of :class:`~eaglemission.detectors.dtdmi.DTDMIDetector` follows. Where the paper leaves a choice
open, the choice is a parameter and is documented in docs/paper_choices.md ("DTDMI").

References
----------
.. [1] "Biological Eagle-eye Inspired Target Detection for Unmanned Aerial Vehicles Equipped
   with a Manipulator" (eagle-eye multi-camera sensor and the DTDMI saliency method), Sec. 2,
   Eqs. (1)-(15). DOI unknown.
"""

from __future__ import annotations

from eaglemission.detectors.dtdmi.equations_dynamic import (
    DERIVATIVE_MASK,
    box_sum,
    competitive_selection,
    delay_update,
    derivative_xy,
    eigenvalue_discrepancy,
    gradient_response,
    inhibition_output,
    multiscale_synthesis,
    shift_neighbour,
    structure_tensor,
    synthesis_2d,
    tau_steps,
)
from eaglemission.detectors.dtdmi.equations_fusion import (
    boosted_saliency,
    final_saliency,
    fused_saliency_max,
)
from eaglemission.detectors.dtdmi.equations_static import (
    LOG_LMS_TO_LAB,
    RGB_TO_LMS,
    FloatArray,
    bin_contrast_cue,
    block_contrast_cue,
    contrast_cue,
    distribution_cue,
    gaussian_centre_weight,
    inverse_square_distance,
    lms_to_lalphabeta,
    normalize_cue,
    rgb_to_lms,
    spatial_cue,
    spatial_cue_sequence,
    srgb_to_linear,
    static_saliency,
)

__all__ = [
    "FloatArray",
    "DERIVATIVE_MASK",
    "box_sum",
    "competitive_selection",
    "delay_update",
    "derivative_xy",
    "eigenvalue_discrepancy",
    "gradient_response",
    "inhibition_output",
    "multiscale_synthesis",
    "shift_neighbour",
    "structure_tensor",
    "synthesis_2d",
    "tau_steps",
    "boosted_saliency",
    "final_saliency",
    "fused_saliency_max",
    "LOG_LMS_TO_LAB",
    "RGB_TO_LMS",
    "bin_contrast_cue",
    "block_contrast_cue",
    "contrast_cue",
    "distribution_cue",
    "gaussian_centre_weight",
    "inverse_square_distance",
    "lms_to_lalphabeta",
    "normalize_cue",
    "rgb_to_lms",
    "spatial_cue",
    "spatial_cue_sequence",
    "srgb_to_linear",
    "static_saliency",
]
