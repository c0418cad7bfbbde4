"""DTDMI saliency detector (paper Sec. 2): equations, state, fused kernels, plugin class."""

from eaglemission.detectors.dtdmi.detector import DTDMIConfig, DTDMIDetector

__all__ = ["DTDMIConfig", "DTDMIDetector"]
