"""Names shared across the project, defined once (cf. aerostack2's names/topics.hpp)."""

ENTRY_POINT_PREFIX = "eaglemission."

ROLES: tuple[str, ...] = ("cameras", "vehicles", "detectors", "estimators", "fitters",
                          "trackers", "manipulators", "missions", "worlds", "sections", "judges")

CAMERA_WIDE = "wide"
CAMERA_NARROW = "narrow"

ENV_HARDWARE = "EAGLEMISSION_HW"
ENV_PX4_URL = "EAGLEMISSION_PX4_URL"

PX4_FAILSAFE_PARAMS: tuple[str, ...] = (
    "COM_OBL_RC_ACT", "COM_OF_LOSS_T", "COM_RC_IN_MODE", "NAV_DLL_ACT", "NAV_RCL_ACT",
    "COM_DL_LOSS_T", "COM_LOW_BAT_ACT", "GF_ACTION", "COM_DISARM_LAND", "MPC_XY_CRUISE",
    "MPC_XY_VEL_MAX", "MPC_Z_VEL_MAX_UP", "MPC_Z_VEL_MAX_DN", "MPC_Z_V_AUTO_UP",
    "MPC_Z_V_AUTO_DN", "MPC_TKO_SPEED", "MPC_LAND_SPEED", "RTL_RETURN_ALT", "RTL_DESCEND_ALT",
    "RTL_CONE_ANG")
"""PX4 parameters that decide what the autopilot does on its own (failsafes, autopilot-flown
speeds and heights): read back before every flight and logged."""
