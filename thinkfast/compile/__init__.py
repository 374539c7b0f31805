"""Offline: goal grid (IK), action tree growth (Ruckig primitives, collision checks), shield
paths, verify, info and diff, and the ``thinkfast-compile`` command."""
