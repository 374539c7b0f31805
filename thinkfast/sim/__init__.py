"""Simulators: world models (thrower, camera, rendered frames, EGM controller, RWS controller,
judge) and the runners that use them (lockstep and real-time runs, bench, fault campaign)."""
