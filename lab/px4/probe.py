"""Which simulator a running PX4 SITL flies: its airframe (SYS_AUTOSTART), read on PX4's GCS
link the way a ground station reads it."""

from __future__ import annotations

import os
import struct
import time
from typing import Any

from eaglemission.lab.px4.sitl import AIRFRAMES, SitlError

GCS_LINK = "udpin:0.0.0.0:14550"
"""PX4 SITL's GCS link (QGroundControl's port): PX4 instance 0 sends there."""


def _int_param(msg: Any) -> int:
    """An integer PARAM_VALUE: PX4 sends its bytes in the float field (bytewise encoding)."""
    if int(msg.param_type) in (5, 6):  # MAV_PARAM_TYPE_UINT32, INT32
        return int(struct.unpack("<i", struct.pack("<f", float(msg.param_value)))[0])
    return int(round(float(msg.param_value)))


def airframe_sim(url: str = GCS_LINK, timeout_s: float = 10.0) -> str:
    """``sih`` or ``jmavsim`` from the PX4 sending to ``url`` (pymavlink); raises
    :class:`SitlError` when none answers or the airframe is neither."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(url, source_system=255, source_component=190)
    try:
        deadline = time.monotonic() + timeout_s
        if conn.wait_heartbeat(timeout=timeout_s) is None:
            raise SitlError(f"no PX4 HEARTBEAT on {url} within {timeout_s:g} s: is PX4 SITL "
                            "running (and no ground station holding that port)?")
        autostart: int | None = None
        while autostart is None and time.monotonic() < deadline:
            conn.mav.param_request_read_send(conn.target_system, conn.target_component,
                                             b"SYS_AUTOSTART", -1)
            msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
            if msg is not None and msg.param_id == "SYS_AUTOSTART":
                autostart = _int_param(msg)
        if autostart is None:
            raise SitlError(f"PX4 on {url} did not answer SYS_AUTOSTART within {timeout_s:g} s")
    finally:
        conn.close()
    sim = AIRFRAMES.get(autostart)
    if sim is None:
        raise SitlError(f"PX4 on {url} flies airframe {autostart}, neither SIH (10040) nor "
                        "jMAVSim (10017): set EAGLEMISSION_PX4_SIM=sih|jmavsim")
    return sim
