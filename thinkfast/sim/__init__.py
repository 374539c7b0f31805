"""Simulators: world models (thrower, camera, rendered frames, EGM controller, RWS controller,
judge) and the runners that use them (lockstep and real-time runs, bench, sweeps); the fault
campaign around the real daemon is bench code (bench/faultkit)."""
