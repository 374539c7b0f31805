"""Shield centres along joint 1-3 motions, with the wrist keeping the shield normal fixed.

On the x-y-x wrist (:mod:`thinkfast.robot.wrist`) the shield normal is link_5's x axis, and the
shield centre lies on that axis at a fixed distance ``L`` from the wrist centre (the origin of
link_5, which joint_4 does not move: joint_5 sits on joint_4's axis). So whatever wrist angles
the rule picks for a normal n (branch, 2 pi wraps, joint_6),

    shield centre = wrist centre(q1, q2, q3) + L n,

and the batched FK only has to pose the arm up to link_5 (the tests hold this to the full FK
with the coplanar rule's wrist angles at 1e-12). The constructor checks both conditions on the
robot and refuses a robot where they fail.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from thinkfast.errors import RobotModelError
from thinkfast.robot.batch_fk import BatchFK
from thinkfast.robot.model import Robot
from thinkfast.robot.wrist import check_wrist_geometry


class ShieldSampler:
    """Shield centres [m] in ``base`` for joints 1-3 under a fixed shield normal.

    Args:
        robot: the robot (x-y-x wrist, shield centre on link_5's x axis).

    Raises:
        RobotModelError: the wrist or the shield mounting differs from that.
    """

    def __init__(self, robot: Robot):
        check_wrist_geometry(robot)
        by_name = {j.name: j for j in robot.chain}
        j5 = by_name["joint_5"]
        if not np.allclose(j5.T_parent_joint[1:3, 3], 0.0, atol=1e-12):
            raise RobotModelError("shield path: joint_5 must sit on joint_4's x axis")
        self.robot = robot
        self.fk = BatchFK(robot)
        self.wrist_link = j5.child
        q = np.array(robot.home, dtype=float)[None]
        poses = self.fk.link_poses(q, until=robot.shield_link)
        w, s = poses[self.wrist_link][0], poses[robot.shield_link][0]
        local = w[:3, :3].T @ (s[:3, 3] - w[:3, 3])  # in link_5: along x only
        if not (np.allclose(local[1:], 0.0, atol=1e-9) and np.allclose(w[:3, 0], s[:3, 2])):
            raise RobotModelError(
                "shield path: the shield centre must lie on link_5's x axis, normal along it"
            )
        self.offset = float(local[0])  # L [m]

    def centres(self, q123: np.ndarray, normal=(1.0, 0.0, 0.0)) -> np.ndarray:
        """Shield centres [m], shape (..., 3), for joints 1-3 [rad], shape (..., 3).

        Args:
            q123: joint 1-3 angles, any leading shape (e.g. (M, T, 3)).
            normal: shield normal in ``base`` (unit (3,)); +x is the coplanar rule.
        """
        q123 = np.asarray(q123, dtype=float)
        flat = q123.reshape(-1, 3)
        q = np.zeros((len(flat), 6))
        q[:, :3] = flat
        wc = self.fk.link_poses(q, until=self.wrist_link)[self.wrist_link][:, :3, 3]
        n = np.asarray(normal, dtype=float)
        return (wc + self.offset * (n / np.linalg.norm(n))).reshape(q123.shape)


def sample_joint_paths(trajectories: Sequence, times: np.ndarray) -> np.ndarray:
    """Joint 1-3 positions [rad], shape (M, T, 3), of Ruckig trajectories at ``times`` [s] (T,).

    Each trajectory is read at ``clip(t, 0, duration)``: at its start before 0 and held at its
    end afterwards (every motion here ends at rest).
    """
    times = np.asarray(times, dtype=float)
    out = np.empty((len(trajectories), len(times), 3))
    for m, traj in enumerate(trajectories):
        dur = traj.duration
        for i, t in enumerate(np.clip(times, 0.0, dur).tolist()):
            out[m, i] = traj.at_time(t)[0]
    return out
