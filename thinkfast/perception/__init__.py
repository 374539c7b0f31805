"""Perception front end: ZED frames (left image + XYZ point cloud) -> ball detections.

``frame`` (the frame message), ``boxes`` (external 2-D boxes), ``colour`` (HSV blobs),
``cloud`` (box shrink, robust 3-D centre), ``detect`` (one frame -> one detection), ``config``,
and the edges: ``node`` (zenoh) and ``cli`` (``thinkfast-detect``). docs/CAMERA_FRAMES.md.
"""
