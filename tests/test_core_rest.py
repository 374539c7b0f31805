"""The reply process's time base at rest: a stalling controller's lag is lined up again.

The reply process's core (:class:`ControlCore` around a :class:`PlanFollower`) answers a
controller whose ``tm`` jitters by +-1 ms in whole milliseconds and whose own stalls make its
stamps jump while its servo moves one cycle (``seqno`` +1): the controller time lags the wall
clock by the stalls. The plans come from the real executor (small compiled tree, real Ruckig)
through the plan vector, as the planner process publishes them; the executor steps where the
follower stepped and takes the follower's replans, as :mod:`thinkfast.daemon.planner_process` does.
"""

import numpy as np
import pytest

from tests.conftest import compile_small_tree
from thinkfast.control.config import RunConfig
from thinkfast.control.core import ControlCore
from thinkfast.control.executor import IDLE, RETURNING, Executor
from thinkfast.control.link import Feedback
from thinkfast.control.plan import PlanFollower, decode_plan, executor_plan, plan_key
from thinkfast.control.safety import SafetySupervisor, robot_limits
from thinkfast.decide.tree_view import runtime_tree
from thinkfast.tree.file import load_tree

CFG = RunConfig()
DT = CFG.safety.dt
T0 = 1.7e9  # wall clock of the first packet [s]
STALL = 0.03  # s: the controller's own stall, every STALL_EVERY packets
STALL_EVERY = 150


@pytest.fixture(scope="module")
def rtree(tmp_path_factory, robot):
    path = compile_small_tree(tmp_path_factory.mktemp("rest"), spacing=0.15)
    return runtime_tree(load_tree(path), robot, CFG)


class _Split:
    """The planner (executor) and the reply loop (core around a follower), in one process."""

    def __init__(self, rtree, robot, q0):
        self.ex = Executor(rtree, robot, CFG, "naive")
        self.follower = PlanFollower(robot, CFG)
        sup = SafetySupervisor(robot_limits(robot, CFG.safety.position_margin), CFG.safety,
                               robot.home)  # fmt: skip
        self.core = ControlCore(self.follower, sup, CFG.safety)
        self.q0, self.key, self.plan_id = q0, None, 0
        self.k, self.wall = -1, T0  # the last packet's index and wall clock [s]

    def publish(self):
        """The planner's side between two packets: step the executor where the follower did,
        take the follower's replans, publish a changed plan; the follower adopts it."""
        ex, f, core = self.ex, self.follower, self.core
        for name, t, q, qd, qdd in f.calls:
            if name == "resync":
                ex.resync(q, qd, qdd, t)
            else:
                getattr(ex, name)(q, t)
        f.calls.clear()
        if f.t_set == core.clock.t:
            ex.wrist.reset(core.sup.q[3:], f.t_set, core.sup.qd[3:], core.sup.qdd_end[3:])
            ex.setpoint(f.t_set)
        key = plan_key(ex, f.epoch)
        if key != self.key:
            self.key, self.plan_id = key, self.plan_id + 1
            plan = decode_plan(executor_plan(ex, self.plan_id, f.epoch))
            if f.takes(plan):
                core.invalidate()
                f.adopt(plan)
        core.prepare()

    def run(self, seconds: float, rng):
        """Packets for ``seconds`` of the controller's cycles; returns per packet (wall time
        [s], controller time [s], commanded joints [rad] (6,), executor mode)."""
        out = []
        n = round(seconds / DT)
        for _ in range(n):
            self.k += 1
            k = self.k
            self.wall += DT + (STALL if k and k % STALL_EVERY == 0 else 0)
            tm = (round(self.wall * 1000) + int(rng.integers(-1, 2))) % (1 << 32)
            now = self.wall + 0.0002
            q = self.q0 if self.core.last is None else self.core.sup.q
            r = self.core.on_feedback(Feedback(tm, q, 1000 + k), now)
            assert r is not None
            if k == 0:
                self.ex.start_from(self.q0, r.tick.t)
                self.follower.start_from(self.q0, r.tick.t)
                self.follower.calls.clear()
                self.follower.epoch = 0  # the executor made the same start
            self.core.settle()
            self.publish()
            out.append((now, r.tick.t, np.array(r.q), self.ex.mode))
        return out


def test_a_stalling_controller_s_lag_is_lined_up_once_the_plan_is_at_rest(rtree, robot):
    """The arm returns home from away (the controller stalls now and then: its time lags the
    wall clock by the stalls), then rests: at rest the time base is lined up with the arrivals
    again (the next throw's plan is placed on the clock the ball's detections are stamped on),
    and the commanded joints do not move for it."""
    away = robot.home + np.array([0.6, -0.3, 0.3, 0.5, 0.3, -0.4])
    split = _Split(rtree, robot, away)
    moving = split.run(3.0, np.random.default_rng(5))
    assert any(m == RETURNING for *_, m in moving)
    assert moving[-1][3] == IDLE  # home: the planner publishes an idle plan
    lag_moving = max(now - t for now, t, *_ in moving)
    assert lag_moving > 1.5 * STALL  # the stalls while moving made the controller time lag
    rest = split.run(2.0, np.random.default_rng(6))
    assert all(m == IDLE for *_, m in rest)
    lags = np.array([now - t for now, t, *_ in rest])
    # lined up: at most the stalls within the anchor window (1 s), never their sum
    assert lags[-250:].min() > -0.001 and lags[-250:].max() < 2 * STALL + 0.005, lags[-250:]
    q = np.array([x[2] for x in rest])
    assert np.ptp(q, axis=0).max() < 1e-12  # the time base moved, no setpoint did
