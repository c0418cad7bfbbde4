"""Names shared across the project, defined once (cf. aerostack2's names/topics.hpp)."""

ENTRY_POINT_PREFIX = "eaglemission."

ROLES: tuple[str, ...] = ("cameras", "vehicles", "detectors", "estimators", "missions")

CAMERA_WIDE = "wide"
CAMERA_NARROW = "narrow"

ENV_HARDWARE = "EAGLEMISSION_HW"
ENV_PX4_URL = "EAGLEMISSION_PX4_URL"
