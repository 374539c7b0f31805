"""The look-ahead's inputs from the run configuration (``[value] backup = "lookahead"``).

The preposterior values of :mod:`thinkfast.decide.lookahead` need what the coming detections
will be worth: the default camera's frame rate (``[camera] fps``), its position and stereo
noise in its mode (the filter parameters of ``[camera]``), and when the arm must choose next.
:func:`foresight` builds that once per planner or hedge stage;
:func:`thinkfast.decide.lookahead.ahead` turns a belief into the crossing belief at the
commit time, or None where the look-ahead would not change the values (no frame comes before
the commit, or the coming frames move the crossing point's expected position by less than
``[value] lookahead_min_std``: QMDP then). Several cameras: the default camera's frames alone
are counted (the look-ahead then undervalues waiting a little).
"""

from __future__ import annotations

import numpy as np

from thinkfast.control.config import RunConfig, default_camera_filter
from thinkfast.decide import lookahead as lk
from thinkfast.decide.tree_view import RuntimeTree


def foresight(tree: RuntimeTree, cfg: RunConfig) -> lk.Foresight | None:
    """The camera model of the look-ahead, None with ``[value] backup = "qmdp"``."""
    if cfg.value.backup != "lookahead":
        return None
    sensor = tree.plane.to_plane(np.array(cfg.camera.xyz, dtype=float))
    return lk.Foresight(default_camera_filter(cfg), sensor, 1.0 / cfg.camera.fps)
