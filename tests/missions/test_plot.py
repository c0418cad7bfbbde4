"""The flight figure of ``run --plot`` and ``log --plot`` on a flown normal and a flown
interrupted (Ctrl-C -> return) simulated mission: PNG written, nothing laid over the data or
the axis labels, the top view fitted to the flight, the return visible in it."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import cv2
import matplotlib.pyplot as plt
import pytest
from eaglemission.missions.flight_figure import RETURN_STATES, flight_figure, state_colour
from eaglemission.missions.plot import (
    outcome_picture,
    plot_outcome,
    plot_recording,
    recording_picture,
)
from matplotlib.colors import to_hex
from mission_helpers import variant

from eaglemission.config import MissionFile, load_config
from eaglemission.flight.run import FlightOptions, fly_sync
from eaglemission.interfaces import MissionHooks


@pytest.fixture(scope="module")
def cfg() -> MissionFile:
    cfg = load_config(check_plugins=False)
    return variant(cfg, detector={"type": "mss", "params": {"downscale": 2}})


@pytest.fixture(scope="module")
def flights(cfg):
    """(normal, interrupted) outcomes: the embedded mission flown to DONE, and the same
    interrupted by SIGINT 6 s into the coarse approach (it returns home and lands)."""
    from eaglemission.lab.campaign.sim import run_simulation  # noqa: F401  (plugins importable)

    normal = fly_sync(cfg, FlightOptions()).outcome

    async def ctrl_c_in_approach(mission):
        while mission.state is None or mission.state.value != "COARSE_APPROACH":
            await mission.parts.clock.sleep(0.1)
        await mission.parts.clock.sleep(6.0)
        os.kill(os.getpid(), signal.SIGINT)

    interrupted = fly_sync(cfg, FlightOptions(handle_signals=True, hooks=MissionHooks(
        side_tasks=(ctrl_c_in_approach,)))).outcome
    assert normal.final_state == "DONE", normal.reason
    assert interrupted.final_state == "FAILSAFE" and interrupted.result.action == "return"
    return normal, interrupted


def _overlaps(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


@pytest.mark.parametrize("which", ["normal", "interrupted"])
def test_plot_outcome_and_recording_write_pngs(flights, cfg, tmp_path: Path, which: str):
    out = flights[which == "interrupted"]
    plot_outcome(out, cfg, tmp_path / "run.png")
    plot_recording(out.log.records, cfg, tmp_path / "log.png")
    for name in ("run.png", "log.png"):
        img = cv2.imread(str(tmp_path / name))
        assert img is not None and img.shape[0] > 400 and img.shape[1] > 800


@pytest.mark.parametrize("which", ["normal", "interrupted"])
def test_title_and_legends_lie_off_the_data_and_the_axis_labels(flights, cfg, which: str):
    out = flights[which == "interrupted"]
    for pic in (outcome_picture(out), recording_picture(out.log.records)):
        fig = flight_figure(pic, cfg)
        try:
            fig.canvas.draw()
            r = fig.canvas.get_renderer()
            top, alt, legends = fig.axes
            data_axes = [top, alt]
            covers = [fig._suptitle.get_window_extent(r)]
            covers += [leg.get_window_extent(r) for leg in legends.get_children()
                       if leg.__class__.__name__ == "Legend"]
            assert len(covers) == 3  # the title, the states' and the top view's legends
            keep = [a.get_window_extent(r) for a in data_axes]
            keep += [lab.get_window_extent(r) for a in data_axes
                     for lab in (a.xaxis.label, a.yaxis.label, a.title)]
            for c in covers:
                for k in keep:
                    assert not _overlaps(c, k), (c, k)
            assert not any(a.get_legend() for a in data_axes)  # no legend inside an axes
            # the state changes are coloured bands, not text on the plot
            assert not [t for t in alt.texts if t.get_text() in {s for _, s, _ in pic.states}]
        finally:
            plt.close(fig)


def test_top_view_fits_the_flight_not_the_route(flights, cfg):
    for out in flights:
        pic = outcome_picture(out)
        fig = flight_figure(pic, cfg)
        try:
            fig.canvas.draw()
            top = fig.axes[0]
            n0, n1 = top.get_ylim()
            far = max(pic.north_m + ([pic.target_ne_m[0]] if pic.target_ne_m else []))
            # the route runs to 40 m north; the view ends a few metres past the flight and
            # the target
            assert far < n1 <= far + 5 and n0 >= min(pic.north_m) - 5
            # the top view's box fills its column (no large empty area beside it)
            slot = top.get_subplotspec().get_position(fig)
            assert top.get_position().width >= 0.75 * slot.width
        finally:
            plt.close(fig)


def test_the_return_of_an_interrupted_flight_shows_in_the_top_view(flights, cfg):
    normal, interrupted = flights
    for out, returned in ((normal, False), (interrupted, True)):
        pic = outcome_picture(out)
        fig = flight_figure(pic, cfg)
        try:
            top = fig.axes[0]
            wide = [ln for ln in top.get_lines()
                    if to_hex(ln.get_color()) in {state_colour(s) for s in RETURN_STATES}
                    and ln.get_linewidth() >= 5]
            assert bool(wide) == returned
            if returned:
                north = wide[0].get_ydata()
                # from where the operator stopped it, back to home
                assert max(north) > 5.0 and abs(north[-1]) < 1.5
                labels = [t.get_text() for leg in fig.axes[2].get_children()
                          if leg.__class__.__name__ == "Legend" for t in leg.get_texts()]
                assert "FAILSAFE: the return (wide)" in labels and "end (landed)" in labels
        finally:
            plt.close(fig)
