"""Manipulator plugins that need no simulation: the ``fixed`` tool (the servo arm on the
autopilot's actuator outputs lives with the MAVSDK driver, drivers/vehicles/mavsdk/arm.py)."""
