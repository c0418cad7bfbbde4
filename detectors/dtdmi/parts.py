"""Plugins ``cluster_static`` and ``midbrain``: one part of DTDMI alone.

``cluster_static`` is the static cluster saliency S_s (Eqs. (1)-(6) of [1], Sec. 2.1),
``midbrain`` the dynamic map S_M (Eqs. (7)-(14), Sec. 2.2). Both are
:class:`~eaglemission.detectors.dtdmi.DTDMIDetector`; their ``Config`` fixes the other part off.

References
----------
.. [1] Eagle-eye inspired target detection (DTDMI), Sec. 2. DOI unknown.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from eaglemission.detectors.dtdmi.config import DTDMIConfig
from eaglemission.detectors.dtdmi.detector import DTDMIDetector


class ClusterStaticConfig(DTDMIConfig):
    """DTDMI parameters with the dynamic part switched off."""

    use_static: Literal[True] = True
    use_dynamic: Literal[False] = False


class MidbrainDynamicConfig(DTDMIConfig):
    """DTDMI parameters with the static part switched off."""

    use_static: Literal[False] = False
    use_dynamic: Literal[True] = True


class ClusterStaticDetector(DTDMIDetector):
    """Static cluster saliency S_s alone (LMS colour clusters, contrast x spatial cue)."""

    Config: ClassVar[type[DTDMIConfig]] = ClusterStaticConfig
    description: ClassVar[str] = "DTDMI static cluster saliency alone (paper Eqs. 1-6)"


class MidbrainDynamicDetector(DTDMIDetector):
    """Eagle-midbrain dynamic perception S_M alone (delay units, correlators, texture contrast)."""

    Config: ClassVar[type[DTDMIConfig]] = MidbrainDynamicConfig
    description: ClassVar[str] = "DTDMI midbrain dynamic map alone (paper Eqs. 7-14)"
