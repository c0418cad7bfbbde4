"""Simulated manipulators (the ``simulated_arm`` plugin)."""
