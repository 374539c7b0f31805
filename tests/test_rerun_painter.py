"""The Rerun painter's text: one line per chosen motion (its geometry: tests/test_scene.py; the
painter on a real stream: tests/test_view_live.py)."""

from __future__ import annotations

import pytest

from thinkfast.view.rerun_painter import motion_text


@pytest.mark.parametrize(
    "kind, ref, goal, value, text",
    [
        ("steer", 3, 7, 0.8125, "direct move to goal 7, value 0.812"),
        ("edge", 12, -1, None, "tree branch into node 12"),
        ("terminal", 4, 9, 0.5, "terminal edge 4 to goal 9, value 0.500"),
        ("return", 0, -1, None, "return home"),
        ("wobble", 0, -1, None, "wobble"),
    ],
)
def test_each_motion_is_one_line(kind, ref, goal, value, text):
    assert motion_text(kind, ref, goal, value) == text
