"""The robot: URDF + robot.toml, loaded and validated once, frozen afterwards.

``load_robot(path)`` reads ``robot.toml`` (which names its URDF), builds the Pinocchio model and
parses the URDF collision primitives. Every array is resolved against the model's joint order and
frozen, so downstream code indexes joints 0..5 = joint_1..joint_6.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import math
import os
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from thinkfast.config import from_dict, load_toml, spec
from thinkfast.contract.frames import PlanePose
from thinkfast.errors import ConfigError, RobotModelError
from thinkfast.robot import fixed_order as fo
from thinkfast.robot import toml_checks


def frozen(a) -> np.ndarray:
    """A read-only float64 copy of ``a``."""
    out = np.array(a, dtype=np.float64)
    out.setflags(write=False)
    return out


@dataclass(frozen=True)
class CellObject:
    """A static collision object of the cell, in the ``base`` frame."""

    name: str = spec(doc="object name, used in collision reports")
    shape: str = spec(choices=("box", "cylinder", "sphere"), doc="primitive kind")
    size: tuple[float, ...] = spec(
        lo=0.0,
        lo_open=True,
        unit="m",
        doc="box: [x, y, z]; cylinder: [radius, length]; sphere: [radius]",
    )
    xyz: tuple[float, ...] = spec((0.0, 0.0, 0.0), length=3, unit="m", doc="centre in base")
    rpy: tuple[float, ...] = spec(
        (0.0, 0.0, 0.0),
        length=3,
        unit="rad",
        lo=-math.tau,
        hi=math.tau,
        doc="orientation in base (radians, within one turn)",
    )


@dataclass(frozen=True)
class RobotToml:
    """Schema of ``robot.toml`` (see robots/irb1600/README.md for the sources of the numbers)."""

    name: str = spec(doc="robot name")
    urdf: str = spec(doc="URDF path, relative to robot.toml")
    joints: tuple[str, ...] = spec(length=6, doc="controlled joints, in EGM order")
    # One value per joint (toml_checks.check_lengths); limits checked against the URDF there.
    max_velocity: tuple[float, ...] = spec(lo=0.0, lo_open=True, unit="rad/s")
    max_acceleration: tuple[float, ...] = spec(lo=0.0, lo_open=True, unit="rad/s^2")
    max_jerk: tuple[float, ...] = spec(lo=0.0, lo_open=True, unit="rad/s^3")
    home: tuple[float, ...] = spec(
        (), unit="rad", doc="home configuration (optional: the compile config solves it)"
    )
    shield_link: str = spec("shield", doc="link whose single cylinder collision is the shield")
    allowed_collisions: tuple[tuple[str, ...], ...] = spec(
        (), doc="link pairs never checked against each other (envelopes that always touch)"
    )
    cell: tuple[CellObject, ...] = spec((), doc="static collision objects of the cell")
    positioning_joints: int = spec(
        3, lo=1, doc="joints that place the shield (joints 1..n), the wrist's are the rest"
    )


@dataclass(frozen=True)
class CollisionShape:
    """One collision primitive attached to a link (or to the cell when ``link`` is empty)."""

    link: str
    shape: str  # "box" | "cylinder" | "sphere" | "mesh"
    size: tuple[float, ...]  # box (x, y, z); cylinder (radius, length); sphere (radius,)
    T_link_shape: np.ndarray  # (4, 4) pose of the shape in its link frame
    mesh_path: str = ""


@dataclass(frozen=True)
class UrdfJoint:
    """One URDF joint: parent/child links, origin (4, 4) in the parent link, axis, movable index."""

    name: str
    parent: str
    child: str
    T_parent_joint: np.ndarray
    axis: np.ndarray  # unit (3,) in the joint frame; zeros for fixed joints
    index: int  # index into q (0..5) for movable joints, -1 for fixed


@dataclass(frozen=True)
class Robot:
    """Everything static about the arm, resolved once.

    Attributes:
        model: Pinocchio model (joint order = ``joint_names``).
        q_lower, q_upper: position limits from the URDF [rad], shape (6,).
        v_max, a_max, j_max: velocity [rad/s], acceleration [rad/s^2], jerk [rad/s^3], shape (6,).
        home: home configuration [rad], shape (6,): robot.toml's, or the tree's
            (:meth:`with_home`); None when robot.toml gives none and no tree set it.
        home_solved: the home was solved for a cell (``thinkfast.compile.home``), not read.
        shapes: link collision primitives parsed from the URDF.
        cell: static collision objects in ``base``.
        link_parent: parent link of every link (root maps to "").
        shield_radius, shield_thickness: shield disk [m].
        placement: where the forward kinematics is expressed: None in ``base`` (as loaded);
            a :class:`PlanePose` in that plane's frame (:meth:`placed`), where the
            intercept plane is ``x = distance`` and the cell objects stand where they are.
    """

    name: str
    model: pin.Model
    joint_names: tuple[str, ...]
    q_lower: np.ndarray
    q_upper: np.ndarray
    v_max: np.ndarray
    a_max: np.ndarray
    j_max: np.ndarray
    home: np.ndarray | None
    shapes: tuple[CollisionShape, ...]
    cell: tuple[CollisionShape, ...]
    link_parent: dict[str, str]
    chain: tuple[UrdfJoint, ...]  # URDF joints ordered parents first
    allowed_collisions: frozenset[frozenset[str]]
    shield_link: str
    shield_radius: float
    shield_thickness: float
    urdf_path: Path
    toml_path: Path
    urdf_sha256: str
    toml_sha256: str
    placement: PlanePose | None = None
    positioning_joints: int = 3  # robot.toml positioning_joints; see n_arm
    home_solved: bool = False

    # ---- sizes (every ABB arm here: 6 joints, 3 positioning and a 3-joint wrist)
    @property
    def n_joints(self) -> int:
        """Controlled joints (EGM order): the length of every joint vector."""
        return len(self.joint_names)

    @property
    def n_arm(self) -> int:
        """Positioning joints, ``q[:n_arm]`` (the tree's joints); the wrist is ``q[n_arm:]``."""
        return self.positioning_joints

    @property
    def root_link(self) -> str:
        """The link every pose is expressed in (``base_link``, or ``plane`` when placed)."""
        return next(link for link, parent in self.link_parent.items() if not parent)

    def with_home(self, q) -> Robot:
        """This robot with another home than robot.toml's (a tree's, a solved one:
        ``home_solved``), checked against the limits.

        Raises:
            RobotModelError: ``q`` is not one finite value per joint inside the position limits.
        """
        h = np.array(q, dtype=np.float64).reshape(-1)
        if h.shape != (self.n_joints,) or not np.all(np.isfinite(h)):
            raise RobotModelError(
                f"{self.toml_path}: a home needs {self.n_joints} finite values, got {list(h)}"
            )
        outside = np.flatnonzero((h < self.q_lower) | (h > self.q_upper))
        if outside.size:
            j = int(outside[0])
            raise RobotModelError(
                f"{self.toml_path}: home {self.joint_names[j]} = {h[j]:+.4f} rad is outside "
                f"[{self.q_lower[j]:+.4f}, {self.q_upper[j]:+.4f}]"
            )
        return dataclasses.replace(self, home=frozen(h), home_solved=True)

    @property
    def any_q(self) -> np.ndarray:
        """A valid configuration for checks that hold in every one (rigid links, the wrist's
        geometry): the home, or zero clipped into the limits where there is none yet."""
        if self.home is not None:
            return self.home
        return np.clip(np.zeros(self.n_joints), self.q_lower, self.q_upper)

    def require_home(self, hint: str = "pass the tree (--tree) whose home it is") -> np.ndarray:
        """The home, or a clear refusal where robot.toml gives none and no tree set it.

        Raises:
            RobotModelError: naming robot.toml and ``hint``.
        """
        if self.home is None:
            raise RobotModelError(f"{self.toml_path} gives no home (its trees solve one): {hint}")
        return self.home

    def placed(self, plane: PlanePose) -> Robot:
        """This robot with its forward kinematics in ``plane``'s frame.

        Every pose of every kinematics built on the result (Pinocchio, the batched FK, the
        shield sampler, the wrist rule, collision) is then in the plane's frame: the URDF's
        root hangs from a fixed joint ``plane_placement`` (``T_plane_base``) and the cell
        objects (robot.toml, in ``base``) are moved with it. A plane without a pose
        (``plane.identity``) changes no number: the same model and chain, bit for bit.

        Raises:
            RobotModelError: the robot is placed already.
        """
        if self.placement is not None:
            raise RobotModelError(f"{self.toml_path}: the robot is placed in a plane already")
        if plane.identity:
            return dataclasses.replace(self, placement=plane)
        T = plane.matrix()
        M = pin.SE3(np.array(T[:3, :3]), np.array(T[:3, 3]))
        model = self.model.copy()
        for j in range(1, model.njoints):
            if model.parents[j] == 0:
                model.jointPlacements[j] = M * model.jointPlacements[j]
        for i in range(1, len(model.frames)):  # frame 0 is the universe: now the plane
            f = model.frames[i]
            if f.parentJoint == 0:
                f.placement = M * f.placement
                model.frames[i] = f
        root = self.root_link
        T_joint = np.array(T)
        T_joint.setflags(write=False)
        axis = np.zeros(3)
        axis.setflags(write=False)
        mount = UrdfJoint("plane_placement", PLANE_LINK, root, T_joint, axis, -1)
        parents = {PLANE_LINK: "", **{k: v or PLANE_LINK for k, v in self.link_parent.items()}}
        cell = tuple(
            dataclasses.replace(c, T_link_shape=_placed(T, c.T_link_shape)) for c in self.cell
        )
        return dataclasses.replace(
            self,
            model=model,
            chain=(mount, *self.chain),
            link_parent=parents,
            cell=cell,
            placement=plane,
        )


PLANE_LINK = "plane"  # the root link of a placed robot (docs/INTERFACES.md, "Frames")


def _placed(T: np.ndarray, T_shape: np.ndarray) -> np.ndarray:
    out = fo.matmul(T, T_shape)
    out.setflags(write=False)
    return out


def default_robot_path() -> Path:
    """``robots/irb1600/robot.toml`` of this checkout."""
    return Path(__file__).resolve().parents[2] / "robots" / "irb1600" / "robot.toml"


def load_robot(toml_path: str | Path | None = None) -> Robot:
    """Load ``robot.toml`` and its URDF.

    Raises:
        ConfigError: robot.toml is missing, malformed or has an invalid key, or a limit, the
            home or a link name disagrees with the URDF or is implausible (:mod:`toml_checks`).
        RobotModelError: the URDF is missing, malformed or inconsistent with robot.toml.
    """
    toml_path = Path(toml_path) if toml_path is not None else default_robot_path()
    cfg = from_dict(RobotToml, load_toml(toml_path), str(toml_path))
    toml_checks.check_lengths(cfg, str(toml_path))
    urdf_path = (toml_path.parent / cfg.urdf).resolve()
    if not urdf_path.is_file():
        raise RobotModelError(f"{urdf_path}: URDF file not found (named by {toml_path}: urdf)")
    urdf_text = urdf_path.read_bytes()
    try:
        root = ET.fromstring(urdf_text)
    except ET.ParseError as exc:
        raise RobotModelError(f"{urdf_path}: malformed URDF XML ({exc})") from None
    link_parent = _link_parents(root, urdf_path)
    chain = _parse_chain(root, urdf_path)
    shapes = _parse_shapes(root, urdf_path)  # before Pinocchio: our messages are the clearer ones
    with _captured_stderr() as native_log:
        try:
            model = pin.buildModelFromXML(urdf_text.decode("utf-8"))
        except Exception as exc:  # Pinocchio raises plain ValueError/RuntimeError
            detail = " ".join(native_log().split()) or str(exc)
            raise RobotModelError(
                f"{urdf_path}: Pinocchio cannot build the model ({detail})"
            ) from None

    names = tuple(model.names[1:])
    if names != cfg.joints:
        raise RobotModelError(
            f"{urdf_path}: movable joints {list(names)} do not match {toml_path}: joints "
            f"{list(cfg.joints)}"
        )
    q_lower, q_upper = frozen(model.lowerPositionLimit), frozen(model.upperPositionLimit)
    where = (str(toml_path), urdf_path.name)
    toml_checks.check_limits(cfg, q_lower, q_upper, model.velocityLimit, *where)
    cylinders = [s.link for s in shapes if s.shape == "cylinder"]
    shields = [k for k in link_parent if cylinders.count(k) == 1]
    toml_checks.check_links(cfg, link_parent, shields, *where)
    shield = [s for s in shapes if s.link == cfg.shield_link]
    if len(shield) != 1 or shield[0].shape != "cylinder":
        raise RobotModelError(
            f"{urdf_path}: link {cfg.shield_link!r} must have exactly one cylinder collision"
        )
    return Robot(
        name=cfg.name,
        model=model,
        joint_names=names,
        q_lower=q_lower,
        q_upper=q_upper,
        v_max=frozen(cfg.max_velocity),
        a_max=frozen(cfg.max_acceleration),
        j_max=frozen(cfg.max_jerk),
        home=frozen(cfg.home) if cfg.home else None,
        shapes=tuple(shapes),
        cell=tuple(_cell_shape(c, i, toml_path) for i, c in enumerate(cfg.cell)),
        link_parent=link_parent,
        chain=_index_chain(chain, names, urdf_path),
        allowed_collisions=frozenset(frozenset(p) for p in cfg.allowed_collisions),
        shield_link=cfg.shield_link,
        shield_radius=shield[0].size[0],
        shield_thickness=shield[0].size[1],
        urdf_path=urdf_path,
        toml_path=toml_path.resolve(),
        urdf_sha256=hashlib.sha256(urdf_text).hexdigest(),
        toml_sha256=hashlib.sha256(toml_path.read_bytes()).hexdigest(),
        positioning_joints=_positioning_joints(cfg, str(toml_path)),
    )


SUPPORTED_POSITIONING = 3  # the tree's joints (node_state: position, velocity, acceleration)


def _positioning_joints(cfg: RobotToml, source: str) -> int:
    """robot.toml ``positioning_joints``, checked: the split the tree format holds (its
    ``node_state`` is joints 1-3: docs/TREE_FORMAT.md), with joints left for the wrist."""
    n, k = len(cfg.joints), cfg.positioning_joints
    if k != SUPPORTED_POSITIONING or k >= n:
        raise ConfigError(source, "positioning_joints", f"{k} is not supported: the action "
                          f"tree holds joints 1-{SUPPORTED_POSITIONING} of {n} (give "
                          f"{SUPPORTED_POSITIONING} or leave the key out)")  # fmt: skip
    return k


def pose(xyz, rpy) -> np.ndarray:
    """Homogeneous transform (4, 4) from translation [m] and roll-pitch-yaw [rad]."""
    T = np.eye(4)
    T[:3, :3] = pin.rpy.rpyToMatrix(*map(float, rpy))
    T[:3, 3] = xyz
    return T


@contextlib.contextmanager
def _captured_stderr():
    """Capture what native code (urdfdom) writes to file descriptor 2; yields a reader."""
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield lambda: (tmp.seek(0), tmp.read().decode("utf-8", "replace"))[1]
        finally:
            os.dup2(saved, 2)
            os.close(saved)


def _link_parents(root: ET.Element, urdf_path: Path) -> dict[str, str]:
    parents = {link.get("name"): "" for link in root.findall("link")}
    for joint in root.findall("joint"):
        parent, child = joint.find("parent"), joint.find("child")
        if parent is None or child is None:
            raise RobotModelError(f"{urdf_path}: joint {joint.get('name')!r} lacks parent/child")
        parents[child.get("link")] = parent.get("link")
    return parents


def _origin(elem: ET.Element, what: str, urdf_path: Path) -> tuple[tuple[float, ...], ...]:
    """``xyz`` [m] and ``rpy`` [rad] of an element's ``<origin>`` (zeros when absent)."""
    origin = elem.find("origin")
    if origin is None:
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    xyz = _floats(origin.get("xyz", "0 0 0"), 3, f"{what} origin xyz", urdf_path)
    rpy = _floats(origin.get("rpy", "0 0 0"), 3, f"{what} origin rpy", urdf_path)
    return xyz, rpy


def _parse_chain(root: ET.Element, urdf_path: Path) -> list[UrdfJoint]:
    joints = []
    for j in root.findall("joint"):
        name, kind = j.get("name"), j.get("type")
        xyz, rpy = _origin(j, f"joint {name}", urdf_path)
        axis = np.zeros(3)
        if kind in ("revolute", "continuous"):
            ax = j.find("axis")
            axis = np.array(
                _floats(
                    ax.get("xyz") if ax is not None else "1 0 0", 3, f"joint {name} axis", urdf_path
                )
            )
            if fo.norm(axis) < 1e-9:
                raise RobotModelError(f"{urdf_path}: joint {name!r} has a zero axis")
            axis = axis / fo.norm(axis)
        elif kind != "fixed":
            raise RobotModelError(f"{urdf_path}: joint {name!r}: unsupported type {kind!r}")
        T = pose(xyz, rpy)
        T.setflags(write=False)
        axis.setflags(write=False)
        joints.append(
            UrdfJoint(name, j.find("parent").get("link"), j.find("child").get("link"), T, axis, -1)
        )
    ordered, known = [], {root.find("link").get("name")} if root.find("link") is not None else set()
    known |= {lk.get("name") for lk in root.findall("link")} - {j.child for j in joints}
    pending = list(joints)
    while pending:  # parents before children
        ready = [j for j in pending if j.parent in known]
        if not ready:
            raise RobotModelError(f"{urdf_path}: joints do not form a tree")
        for j in ready:
            ordered.append(j)
            known.add(j.child)
            pending.remove(j)
    return ordered


def _index_chain(
    chain: list[UrdfJoint], names: tuple[str, ...], urdf_path: Path
) -> tuple[UrdfJoint, ...]:
    out = []
    for j in chain:
        idx = names.index(j.name) if j.name in names else -1
        if idx < 0 and np.any(j.axis):
            raise RobotModelError(f"{urdf_path}: movable joint {j.name!r} is not controlled")
        out.append(dataclasses.replace(j, index=idx))
    return tuple(out)


def _floats(text: str | None, n: int, what: str, urdf_path: Path) -> tuple[float, ...]:
    try:
        vals = tuple(float(x) for x in (text or "").split())
    except ValueError:
        vals = ()
    if len(vals) != n or not all(np.isfinite(vals)):
        raise RobotModelError(f"{urdf_path}: {what} must be {n} finite numbers, got {text!r}")
    return vals


def _parse_shapes(root: ET.Element, urdf_path: Path) -> list[CollisionShape]:
    shapes = []
    for link in root.findall("link"):
        name = link.get("name")
        for col in link.findall("collision"):
            xyz, rpy = _origin(col, name, urdf_path)
            geom = col.find("geometry")
            if geom is None or len(geom) != 1:
                raise RobotModelError(f"{urdf_path}: link {name!r} collision needs one geometry")
            g = geom[0]
            if g.tag == "box":
                size = _floats(g.get("size"), 3, f"{name} box size", urdf_path)
            elif g.tag == "cylinder":
                size = (
                    _floats(g.get("radius"), 1, f"{name} cylinder radius", urdf_path)[0],
                    _floats(g.get("length"), 1, f"{name} cylinder length", urdf_path)[0],
                )
            elif g.tag == "sphere":
                size = _floats(g.get("radius"), 1, f"{name} sphere radius", urdf_path)
            elif g.tag == "mesh":
                mesh = (urdf_path.parent / g.get("filename", "")).resolve()
                shapes.append(CollisionShape(name, "mesh", (), pose(xyz, rpy), str(mesh)))
                continue
            else:
                raise RobotModelError(f"{urdf_path}: link {name!r}: unsupported geometry {g.tag!r}")
            if min(size) <= 0:
                raise RobotModelError(f"{urdf_path}: link {name!r}: {g.tag} sizes must be > 0")
            T = pose(xyz, rpy)
            T.setflags(write=False)
            shapes.append(CollisionShape(name, g.tag, size, T))
    return shapes


def _cell_shape(obj: CellObject, index: int, toml_path: Path) -> CollisionShape:
    want = {"box": 3, "cylinder": 2, "sphere": 1}[obj.shape]
    if len(obj.size) != want:
        raise ConfigError(
            str(toml_path), f"cell[{index}].size", f"a {obj.shape} needs {want} values"
        )
    T = pose(obj.xyz, obj.rpy)
    T.setflags(write=False)
    return CollisionShape(obj.name, obj.shape, obj.size, T)
