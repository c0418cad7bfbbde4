"""``eaglemission bench`` and ``eaglemission detect``: saliency benchmark and overlay tool.

``bench`` scores detectors on folders laid out as ``<seq>/frames/*.jpg`` + ``<seq>/gt/*.png``
(the layout of ../shared/data/video_saliency/DAVIS2016) with the per-image-mean protocol of
:mod:`eaglemission.detectors.metrics`, and on ``<seq>/boxes.txt`` box annotations (the layout of
../shared/data/uav_tracking) with the box metrics of :mod:`eaglemission.detectors.boxes`, and
writes markdown + JSON tables and plots.
``detect`` runs one detector on a video or an image folder and writes overlay images (heat map,
thresholded regions, MBRs with their corner order). Detectors are loaded only through
``eaglemission.registry.load("detectors", name, params)``. See docs/detectors.md.

The command objects (the ``eaglemission.commands`` entry points) are re-exported from
:mod:`.bench_command` and :mod:`.detect_command`; parameters, data, runs and reports live in
:mod:`.cli_params`, :mod:`.bench_data`, :mod:`.bench_runs` and :mod:`.bench_report`.
"""

from __future__ import annotations

from eaglemission.detectors.bench_command import BENCH_COMMAND
from eaglemission.detectors.detect_command import DETECT_COMMAND

__all__ = ["BENCH_COMMAND", "DETECT_COMMAND"]
