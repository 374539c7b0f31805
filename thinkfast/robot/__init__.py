"""The robot: model from URDF and robot.toml, kinematics (Pinocchio), collision (python-fcl),
the coplanar wrist rule, shield IK and the one Ruckig wrapper (steering)."""
