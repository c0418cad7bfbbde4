"""DTDMI saliency detector (paper Sec. 2): equations, state, fused kernels, plugin class."""

from eaglemission.detectors.dtdmi.config import DTDMIConfig
from eaglemission.detectors.dtdmi.detector import DTDMIDetector

__all__ = ["DTDMIConfig", "DTDMIDetector"]
