"""``eaglemission detect``: run one detector on a video or an image folder and write overlays
(:mod:`.detect_command`). Detectors are loaded only through
``eaglemission.registry.load("detectors", name, params)``. See docs/detectors.md.
"""

from __future__ import annotations

from eaglemission.detectors.detect_command import DETECT_COMMAND

__all__ = ["DETECT_COMMAND"]
