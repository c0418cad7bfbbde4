"""A fresh PX4 SITL instance per flight, from a PX4 build outside the repository.

``python -m eaglemission.lab.px4 start --sim sih|jmavsim --build DIR`` starts PX4 (and jMAVSim)
in an empty working directory and waits for "Ready for takeoff"; ``... stop`` stops it
(:mod:`.sitl`). The tests that need PX4 use it through the ``px4_sitl`` fixture
(tests/conftest.py).
"""
