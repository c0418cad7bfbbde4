"""Simulated worlds: the ground truth the fake drivers share (``world:`` in a mission file)."""
