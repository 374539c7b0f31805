"""Calibration of a real cell: camera pose in ``base`` and the arm's lag and limits.

``thinkfast-calib`` (docs/CALIBRATION.md): ``poses`` picks calibration poses, ``camera`` fits
the camera-to-base transform from a calibration record (:mod:`~thinkfast.calib.camera_record`),
``dynamics`` estimates the controller lag and the acceleration and jerk the arm achieves from a
flight record; ``simulate-camera`` and ``simulate-dynamics`` make records with known answers.
"""
