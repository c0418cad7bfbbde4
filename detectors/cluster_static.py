"""Plugin ``cluster_static``: the static cluster saliency of DTDMI alone (Eqs. (1)-(6) of [1]).

Same code as :class:`~eaglemission.detectors.dtdmi.DTDMIDetector` with the dynamic part off.

References
----------
.. [1] Eagle-eye inspired target detection (DTDMI), Sec. 2.1. DOI unknown.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from eaglemission.detectors.dtdmi.config import DTDMIConfig
from eaglemission.detectors.dtdmi.detector import DTDMIDetector


class ClusterStaticConfig(DTDMIConfig):
    """DTDMI parameters with the dynamic part switched off."""

    use_static: Literal[True] = True
    use_dynamic: Literal[False] = False


class ClusterStaticDetector(DTDMIDetector):
    """Static cluster saliency S_s alone (LMS colour clusters, contrast x spatial cue)."""

    Config: ClassVar[type[DTDMIConfig]] = ClusterStaticConfig
    description: ClassVar[str] = "DTDMI static cluster saliency alone (paper Eqs. 1-6)"
