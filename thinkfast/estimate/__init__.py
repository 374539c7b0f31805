"""Estimate the ball: robust adaptive Kalman filter, launch detector, delta-method crossing at the
plane. Pure kernels over numpy arrays (no I/O, no clocks)."""
