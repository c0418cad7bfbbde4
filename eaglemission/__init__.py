"""eaglemission: eagle-eye inspired dual-camera target detection and approach-to-grasp missions.

The core package holds the types, interfaces, geometry, configuration and registry. Plugins
(drivers, detectors, estimators, missions) live in the top-level folders of the repository and
install as ``eaglemission.drivers``, ``eaglemission.detectors``, ... The core imports no plugin.
"""

__version__ = "0.1.0"
