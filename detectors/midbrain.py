"""Plugin ``midbrain``: the dynamic map of DTDMI alone (Eqs. (7)-(14) of [1]).

Same code as :class:`~eaglemission.detectors.dtdmi.DTDMIDetector` with the static part off.

References
----------
.. [1] Eagle-eye inspired target detection (DTDMI), Sec. 2.2. DOI unknown.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from eaglemission.detectors.dtdmi.config import DTDMIConfig
from eaglemission.detectors.dtdmi.detector import DTDMIDetector


class MidbrainDynamicConfig(DTDMIConfig):
    """DTDMI parameters with the static part switched off."""

    use_static: Literal[False] = False
    use_dynamic: Literal[True] = True


class MidbrainDynamicDetector(DTDMIDetector):
    """Eagle-midbrain dynamic perception S_M alone (delay units, correlators, texture contrast)."""

    Config: ClassVar[type[DTDMIConfig]] = MidbrainDynamicConfig
    description: ClassVar[str] = "DTDMI midbrain dynamic map alone (paper Eqs. 7-14)"
