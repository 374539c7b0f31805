"""Judge one throw: did the true ball (a sphere) meet the shield disk before it crossed the plane?

The shield is the robot's shield cylinder (radius and thickness from the URDF) posed by forward
kinematics of the joint history, linearly interpolated in joint space between samples and held at
the first / last sample outside the history. The ball comes from +x; it is blocked when the
sphere and the solid disk touch at any time from release until its centre crosses
``x = plane_x``. Times are sampled every ``step`` (0.5 ms: the ball moves ~1 cm, a sixth of its
diameter) and the first contact is refined on a finer grid. A shield that reaches the ball's
crossing point only after the crossing is ``"late"``, which is a miss.

A feint (never released) is not blocked or missed: :func:`judge_feint` measures how far the
shield left home and whether it was home again, and at rest, soon after the ball stopped.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from thinkfast.robot.batch_fk import BatchFK
from thinkfast.robot.kinematics import Kinematics
from thinkfast.sim.throws import Throw, ball_positions, plane_crossing

VERDICTS = ("blocked", "late", "missed")
FEINT_WINDOW = 2.0
"""How soon after a feint's ball stops the arm must be home again [s]."""


class Verdict(NamedTuple):
    """Outcome of one throw.

    Attributes:
        blocked: the ball met the shield before its centre crossed the plane.
        t_contact: first contact [s, wall clock of the history], or nan.
        miss_distance: smallest gap between the ball surface and the shield before the crossing
            [m]; 0 when blocked.
        when: wall time [s] of the event ``why`` names: first contact (blocked), first touch of
            the ball held at its crossing point (late), closest approach (missed).
        why: one of :data:`VERDICTS`.
    """

    blocked: bool
    t_contact: float
    miss_distance: float
    when: float
    why: str


def sphere_disk_gap(
    p: np.ndarray, centre: np.ndarray, normal: np.ndarray, radius: float, half_thickness: float,
    ball_radius: float,
) -> np.ndarray:  # fmt: skip
    """Signed gap [m] (N,) between spheres and solid disks (cylinders); negative: overlapping.

    Args:
        p: sphere centres [m], shape (N, 3).
        centre, normal: disk centres [m] and unit normals, shape (N, 3) each.
        radius, half_thickness: disk radius and half its thickness [m].
        ball_radius: sphere radius [m].
    """
    rel = p - centre
    axial = np.einsum("ij,ij->i", rel, normal)
    radial = np.linalg.norm(rel - axial[:, None] * normal, axis=1)
    dr, da = radial - radius, np.abs(axial) - half_thickness
    outside = np.hypot(np.maximum(dr, 0.0), np.maximum(da, 0.0))
    inside = np.minimum(np.maximum(dr, da), 0.0)  # depth inside the cylinder (<= 0)
    return outside + inside - ball_radius


def interpolate_q(t_hist: np.ndarray, q_hist: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Joint angles [rad] (M, 6) at times ``t`` (M,): linear between samples, held outside."""
    return np.stack([np.interp(t, t_hist, q_hist[:, j]) for j in range(q_hist.shape[1])], axis=1)


def judge(
    throw: Throw,
    t_hist: np.ndarray,
    q_hist: np.ndarray,
    kin: Kinematics,
    plane_x: float,
    ball_radius: float,
    t_release_wall: float = 0.0,
    step: float = 5e-4,
    late_window: float = 0.5,
) -> Verdict:
    """Judge ``throw`` against a joint history.

    Args:
        throw: the throw (true ball motion).
        t_hist: history times [s, same wall clock as ``t_release_wall``], shape (N,), increasing.
        q_hist: joint angles [rad], shape (N, 6).
        kin: kinematics of the robot (its shield radius and thickness are used).
        plane_x: the plane the ball must not cross [m].
        ball_radius: ball radius [m].
        t_release_wall: release time of the throw [s, wall clock].
        step: sampling step [s].
        late_window: how long after the crossing to look for a late shield [s].

    Raises:
        ValueError: the history is empty, mis-shaped or not increasing.
    """
    t_hist, q_hist = np.asarray(t_hist, float), np.asarray(q_hist, float)
    if t_hist.ndim != 1 or len(t_hist) == 0 or q_hist.shape != (len(t_hist), 6):
        raise ValueError(f"need t_hist (N,) and q_hist (N, 6), got {t_hist.shape}, {q_hist.shape}")
    if (np.diff(t_hist) <= 0).any():
        raise ValueError("t_hist must be strictly increasing")
    robot = kin.robot
    fk = BatchFK(robot)

    def gap(t_rel: np.ndarray, p: np.ndarray) -> np.ndarray:
        q = interpolate_q(t_hist, q_hist, t_release_wall + t_rel)
        T = fk.link_poses(q, until=robot.shield_link)[robot.shield_link]
        half = 0.5 * robot.shield_thickness
        return sphere_disk_gap(p, T[:, :3, 3], T[:, :3, 2], robot.shield_radius, half, ball_radius)

    t_cross = plane_crossing(throw, plane_x).t
    t = np.append(np.arange(0.0, t_cross, step), t_cross)
    g = gap(t, ball_positions(throw, t))
    hit = np.flatnonzero(g <= 0.0)
    if len(hit):
        i = hit[0]
        t_hit = 0.0
        if i > 0:  # refine on 64 sub-steps, then linearly between the two around the contact
            sub = np.linspace(t[i - 1], t[i], 65)
            gs = gap(sub, ball_positions(throw, sub))
            k = int(np.flatnonzero(gs <= 0.0)[0])
            t_hit = float(sub[k] - gs[k] * (sub[k] - sub[k - 1]) / (gs[k] - gs[k - 1]))
        return Verdict(True, t_release_wall + t_hit, 0.0, t_release_wall + t_hit, "blocked")
    j = int(np.argmin(g))
    miss = float(g[j])
    after = t_cross + np.arange(1, int(math.ceil(late_window / step)) + 1) * step
    p_cross = np.broadcast_to(ball_positions(throw, np.array([t_cross])), (len(after), 3))
    late = np.flatnonzero(gap(after, p_cross) <= 0.0)
    if len(late):
        return Verdict(False, math.nan, miss, float(t_release_wall + after[late[0]]), "late")
    return Verdict(False, math.nan, miss, float(t_release_wall + t[j]), "missed")


class FeintVerdict(NamedTuple):
    """What the arm did about a feint.

    Attributes:
        displacement: largest distance of the shield centre from its home position [m].
        home_after: time [s] after the ball stopped from which the arm stays home (shield centre
            within ``tol``, every joint at rest) to the end of the history; <= 0 when it was
            home from the stop on, nan when it is not home at the end.
        home_again: ``home_after`` <= ``window`` and the history covers the window.
    """

    displacement: float
    home_after: float
    home_again: bool


def judge_feint(
    t_hist: np.ndarray,
    q_hist: np.ndarray,
    kin: Kinematics,
    q_home: np.ndarray,
    t_stop_wall: float,
    window: float = FEINT_WINDOW,
    tol: float = 0.01,
    rest_speed: float = 0.01,
) -> FeintVerdict:
    """Judge the arm's answer to a feint from its joint history.

    Args:
        t_hist: history times [s, wall clock], shape (N,), increasing, N >= 2.
        q_hist: joint angles [rad], shape (N, 6) (commanded or simulated).
        kin: kinematics (the shield link's frame origin is the shield centre).
        q_home: home joint angles [rad], shape (6,).
        t_stop_wall: when the feint's ball stopped moving [s, wall clock].
        window: how soon after the stop the arm must be home again [s].
        tol: distance from home counted as home [m].
        rest_speed: joint speed counted as at rest [rad/s] (finite differences of the history).
    """
    t_hist, q_hist = np.asarray(t_hist, float), np.asarray(q_hist, float)
    if t_hist.ndim != 1 or len(t_hist) < 2 or q_hist.shape != (len(t_hist), 6):
        raise ValueError(f"need t_hist (N>=2,) and q_hist (N, 6), got {t_hist.shape}")
    robot = kin.robot
    fk = BatchFK(robot)
    link = robot.shield_link
    centres = fk.link_poses(np.vstack([q_hist, q_home]), until=link)[link][:, :3, 3]
    dist = np.linalg.norm(centres[:-1] - centres[-1], axis=1)
    speed = np.abs(np.diff(q_hist, axis=0) / np.diff(t_hist)[:, None]).max(axis=1)
    home = (dist <= tol) & (np.r_[speed[0], speed] <= rest_speed)
    away = np.flatnonzero(~home)
    if len(away) and away[-1] == len(t_hist) - 1:
        home_after = math.nan
    else:
        since = t_hist[away[-1] + 1] if len(away) else t_hist[0]
        home_after = float(since - t_stop_wall)
    covered = t_hist[-1] >= t_stop_wall + window
    ok = bool(covered and math.isfinite(home_after) and home_after <= window)
    return FeintVerdict(float(dist.max()), home_after, ok)
