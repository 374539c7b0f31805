"""Lockstep simulation: the daemon's own kernels stepped in simulated time, one process, no sockets.

Per throw: the camera model makes the detections (delivered at their delivery times); every 4 ms
the simulated controller (servo model with transport delay) reports its joints and the daemon's
control core (:class:`~thinkfast.control.core.ControlCore`: executor and safety supervisor
on the controller's clock, checked against the measured joints) answers with the setpoint it
follows; detections reach the core between ticks, exactly as in the daemon's loop. The judge
decides from the controller's joint history.

Planners: every one of the executor's registry (``tree``, ``naive``, ...: the daemon's
executor, :mod:`thinkfast.control.planners.registry`) and ``oracle``: it knows the true crossing
point at release and goes there as fast as the arm allows, so the throws it blocks are the ones
this arm can block at all ("feasible"). ``oracle_seen`` knows the same but leaves only when the
first detection of the flight is delivered (by any camera): no planner that waits for evidence of
the flight can start earlier, so it bounds what any of them can block with these cameras'
latency. The cameras are the run config's (:func:`sim_cameras`: ``[camera]`` and
``[[cameras]]``), or any given to the :class:`World`.

A feint (``thinkfast/sim/thrower.py``) is flown until :data:`FEINT_WINDOW` after its ball stopped
and judged by :func:`~thinkfast.sim.judge.judge_feint` (how far the shield left home, whether it
is home again); the oracles know it is a feint and stay home.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from thinkfast.contract.frames import PlanePose
from thinkfast.control.assembly import CoreAssembly
from thinkfast.control.config import RunConfig
from thinkfast.control.link import Feedback
from thinkfast.control.segments import WristTracker
from thinkfast.decide.tree_view import BALL_RADIUS
from thinkfast.errors import ThinkfastError
from thinkfast.robot.ik import solve_shield_ik
from thinkfast.robot.kinematics import Kinematics
from thinkfast.robot.model import Robot
from thinkfast.robot.shield_path import ShieldSampler
from thinkfast.robot.steering import Steering
from thinkfast.sim.camera import (
    CameraModelConfig,
    SimCamera,
    detection_payload,
    mode_model,
    observe_cameras,
)
from thinkfast.sim.controller import ClockJitter, ServoConfig, SimController, servo_for
from thinkfast.sim.judge import FEINT_WINDOW, judge, judge_feint
from thinkfast.sim.planners import ORACLES
from thinkfast.sim.throws import Throw, plane_crossing
from thinkfast.tree.robot_match import check_robot, place_for_tree

DT = 0.004
LEAD = 0.5  # s of simulated time before the first detection


class Outcome(NamedTuple):
    """Result of one simulated throw with one planner."""

    throw_id: str
    planner: str
    blocked: bool
    why: str
    miss_distance: float
    flight_time: float
    crossing_y: float
    crossing_z: float
    decisions: int
    moved: bool
    start: float  # when the arm was first commanded to move, relative to release [s] (nan: never)
    kind: str = "still"  # the throw's kind (thinkfast/sim/thrower.py)
    displacement: float = math.nan  # feint: largest shield-centre distance from home [m]
    home_after: float = math.nan  # feint: home (1 cm, at rest) from this long after the stop [s]
    home_again: bool = False  # feint: home again within FEINT_WINDOW of the ball stopping
    intervened: int = 0  # ticks on which the safety supervisor changed the plan's setpoint
    faults: int = 0  # deviation (or planner) faults: the supervisor braked and the arm recovered
    commit_start: float = math.nan  # when the confirmed throw's plan took over, after release [s]
    hedges: int = 0  # hedges begun (the hedge stage, control/hedge.py)


class World:
    """Everything shared by all throws of a run (built once per process). ``clock``: the
    simulated controller stamps ``tm`` with a clock that is not hard real-time (each throw its
    own seed), and the core counts cycles by ``seqno``; None: exact stamps, no ``seqno``."""

    def __init__(
        self,
        tree,
        robot: Robot,
        cfg: RunConfig,
        servo: ServoConfig,
        camera: CameraModelConfig,
        cameras: tuple[SimCamera, ...] | None = None,
        clock: ClockJitter | None = None,
    ):
        self.clock = clock
        check_robot(tree.meta, robot)  # the tree's limits, never another robot's
        robot = place_for_tree(tree.meta, robot)  # every pose in the tree's plane's frame
        self.parts = CoreAssembly(tree, robot, cfg)  # the daemon's assembly of the control core
        self.tree = self.parts.tree
        self.robot, self.cfg, self.camera = robot, cfg, camera
        self.servo = servo_for(robot, servo)  # the simulated arm is the tree's robot
        self.cameras = (
            sim_cameras(cfg, camera, self.tree.plane) if cameras is None else tuple(cameras)
        )
        self.kin = Kinematics(robot)
        self.shield = ShieldSampler(robot)  # the oracle's shield centres along its moves
        self.limits = self.parts.limits


def sim_cameras(
    cfg: RunConfig, model: CameraModelConfig, plane: PlanePose | None = None
) -> tuple[SimCamera, ...]:
    """The simulated cameras of a run config: the default camera (``model`` in ``[camera]``'s
    mode and frame rate, :func:`~thinkfast.sim.camera.mode_model`), then every ``[[cameras]]``
    one (``model`` with its latency and frame rate), each where the config says, posed in
    ``plane``'s frame, where the throws fly (None: ``base``)."""
    at = (lambda e: e) if plane is None else plane.camera
    others = tuple(
        SimCamera(
            c.id, dataclasses.replace(model, latency=c.latency, rate=c.fps), at(c.extrinsic())
        )
        for c in cfg.cameras
    )
    return (SimCamera(None, mode_model(cfg.camera, model), at(cfg.camera)), *others)


def simulate(
    world: World, throw: Throw, planner: str, seed: int, oracle_start: float = 0.0
) -> Outcome:
    """Fly one throw against one planner; ``seed`` drives the camera noise (same for all
    planners on the same throw). ``oracle_start``: when the oracle leaves, after release [s].

    For a feint, "release" is the moment its ball stops; ``blocked`` is False.

    Raises:
        ThinkfastError: the throw is aimed at another plane than the tree's.
    """
    robot, cfg = world.robot, world.cfg
    if throw.plane_x != world.tree.plane_x:
        raise ThinkfastError(
            f"throw {throw.id} is aimed at the plane x = {throw.plane_x:g} m, the tree's is "
            f"x = {world.tree.plane_x:g} m: draw the throws at the tree's plane"
        )
    t_rel = LEAD + throw.t_release  # simulated wall time of release
    dets = observe_cameras(throw, world.cameras, seed, t_rel)
    feint = throw.kind == "feint"
    if feint:
        cross, t_end = None, t_rel + FEINT_WINDOW + 0.2
    else:
        cross = plane_crossing(throw)
        t_end = t_rel + cross.t + cfg.throw.after_crossing + 0.15
    clock = world.clock
    if clock is not None:
        clock = dataclasses.replace(clock, seed=clock.seed * 1_000_003 + seed)
    sim = SimController(world.servo, q0=robot.home, clock=clock)
    if planner in ORACLES:
        sup = world.parts.supervisor()
        t_go = t_rel + oracle_start
        if planner == "oracle_seen":
            seen = [d.delivery_time for d in dets if d.capture_stamp > t_rel]
            t_go = min(seen) if seen else math.inf
        step_fn = _stay(robot.home) if feint else _oracle(world, throw, cross, t_go, t_rel)
        ex = None
    else:
        ex = world.parts.executor(planner)  # the registry's planner
        core = world.parts.core(ex)
        sup = core.sup
    k_det, t = 0, 0.0
    moved, t_move = False, math.nan
    while t <= t_end:
        if ex is None:
            q_cmd, qd_cmd = sup.step(*step_fn(t))[:2]
        else:
            while k_det < len(dets) and dets[k_det].delivery_time <= t:
                core.on_detection(detection_payload(dets[k_det]), None, t)
                k_det += 1
            if clock is None:
                reply = core.on_feedback(Feedback(round(t * 1000.0), sim.q), t)
            else:
                seqno, tm = sim.header()
                reply = core.on_feedback(Feedback(tm, sim.q, seqno), t)
            if reply is not None:  # None: unanswered, the controller keeps its last reference
                q_cmd, qd_cmd = reply.q, reply.qd
        if not moved and np.any(np.abs(qd_cmd) > 1e-6):
            moved, t_move = True, t - t_rel
        if ex is None or reply is not None:
            sim.command(q_cmd, qd_cmd, t)
        sim.step(DT)
        t += DT
    hist = sim.history()
    decisions = 0 if ex is None else core.figures().decisions
    guard = (sup.intervened, 0 if ex is None else core.fault_count)
    stage = (math.nan, 0)
    if ex is not None:
        fig = core.figures()
        stage = (fig.t_start - t_rel, fig.hedges)
    if feint:
        f = judge_feint(hist.t, hist.q, world.kin, robot.home, t_rel, FEINT_WINDOW)
        return Outcome(
            throw.id, planner, False, "feint", math.nan, float(throw.flight_time), math.nan,
            math.nan, decisions, moved, t_move, "feint", f.displacement, f.home_after,
            f.home_again, *guard, *stage,
        )  # fmt: skip
    v = judge(throw, hist.t, hist.q, world.kin, throw.plane_x, BALL_RADIUS, t_release_wall=t_rel)
    return Outcome(
        throw.id,
        planner,
        bool(v.blocked),
        v.why,
        float(v.miss_distance),
        float(throw.flight_time),
        float(cross.y),
        float(cross.z),
        decisions,
        moved,
        t_move,
        throw.kind,
        intervened=guard[0],
        faults=guard[1],
        commit_start=stage[0],
        hedges=stage[1],
    )


def _oracle(world: World, throw: Throw, cross, t_go: float, t_rel: float):
    """Setpoint function of the oracle: from ``t_go`` on, a minimum-time move to the exact
    crossing."""
    robot = world.robot
    n = robot.n_arm  # joints of the move; the wrist tracker's: q[n:]
    steer = Steering(robot.v_max[:n], robot.a_max[:n], robot.j_max[:n])
    traj = _oracle_move(world, throw.plane_x, cross, steer, t_rel + cross.t - t_go)
    wrist = WristTracker(robot, 0.0, world.cfg.safety.position_margin)
    wrist.reset(robot.home[n:], 0.0)
    m = wrist.n
    normal = np.array([1.0, 0.0, 0.0])

    def setpoint(t: float):
        s = t - t_go
        if traj is None or s <= 0.0:
            p, v = robot.home[:n], np.zeros(n)
        else:
            p, v, _ = traj.at_time(min(s, traj.duration))
        w = wrist.step(t, np.asarray(p), normal)
        return np.r_[p, w[:m]], np.r_[v, w[m : 2 * m]]

    return setpoint


COVER_STEPS = (1.0 / 3.0, 2.0 / 3.0, 0.95)  # of the shield radius: rings of covering targets
COVER_DIRECTIONS = 8


def _nearest_goal(tree, y: float, z: float) -> np.ndarray:
    """Joint angles (n_joints,) [rad] of the tree's goal nearest ``(y, z)`` on the plane [m]."""
    return tree.goal_q[int(np.argmin(np.sum(np.square(tree.goal_yz - [y, z]), axis=1)))]


def _oracle_move(world: World, plane_x: float, cross, steer: Steering, time_left: float):
    """The oracle's minimum-time move of joints 1-3 from home (a Ruckig trajectory; None when
    Ruckig finds none), leaving ``time_left`` [s] before the crossing. Its target:

    The shield centred on the exact crossing, when the IK reaches it inside the limits and a
    minimum-time move gets there in time. Else (out of reach, or too late) the target of the
    minimum-time move whose shield, at the crossing time, is nearest the crossing: among the
    exact point, every goal of the tree and IK targets on rings within the shield's radius
    around the crossing. A move that passes through the crossing on its way further out gets
    there sooner than one that stops on it, and a covering point nearer home sooner still: the
    oracle is not beaten by a planner's terminal edge that does either."""
    robot, tree = world.robot, world.tree
    normal = (1.0, 0.0, 0.0)
    n = robot.n_arm  # the move's joints, q[:n]
    start = np.r_[robot.home[:n], np.zeros(2 * n)]
    seed = _nearest_goal(tree, cross.y, cross.z)
    ik = solve_shield_ik(world.kin, np.array([plane_x, cross.y, cross.z]), normal, seed)
    found = []
    if ik.converged and _inside(robot, ik.q):
        traj = steer.to_rest(start, ik.q[:n])
        if traj is not None and traj.duration <= time_left:
            return traj
        found.append(ik.q)
    cover = robot.shield_radius
    for step in COVER_STEPS:
        for k in range(COVER_DIRECTIONS):
            a = 2.0 * math.pi * k / COVER_DIRECTIONS
            y, z = cross.y + step * cover * math.cos(a), cross.z + step * cover * math.sin(a)
            ik = solve_shield_ik(
                world.kin, np.array([plane_x, y, z]), normal, _nearest_goal(tree, y, z)
            )
            if ik.converged and _inside(robot, ik.q):
                found.append(ik.q)
    found.extend(tree.goal_q)
    trajs = steer.to_rest_each(start, [q[:n] for q in found])
    at = max(time_left - world.cfg.execution.controller_lag, 0.0)  # the arm lags the command
    q123 = np.array([start[:n] if t is None else t.at_time(min(at, t.duration))[0] for t in trajs])
    centres = world.shield.centres(q123)
    miss = np.hypot(centres[:, 1] - cross.y, centres[:, 2] - cross.z)
    miss[[t is None for t in trajs]] = np.inf
    return trajs[int(np.argmin(miss))]


def _stay(home: np.ndarray):
    """Setpoint function that holds the arm at ``home``."""
    n = len(home)
    return lambda t: (np.array(home, dtype=float), np.zeros(n))


def _inside(robot: Robot, q: np.ndarray) -> bool:
    return bool(np.all(q >= robot.q_lower) and np.all(q <= robot.q_upper))
