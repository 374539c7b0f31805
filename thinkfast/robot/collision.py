"""Self and cell collision checking with python-fcl.

Every URDF collision primitive becomes one fcl object posed by forward kinematics. Pairs checked:
all link pairs except parent/child links, links rigidly attached to each other (checked once when
the model is built: they must not touch) and the pairs robot.toml allows, plus every moving link
against every cell object. A bounding-sphere test in numpy discards far pairs before fcl is asked.
Meshes (if a URDF names any) are loaded with trimesh into fcl BVH models.
"""

from __future__ import annotations

from typing import NamedTuple

import fcl
import numpy as np

from thinkfast.errors import RobotModelError
from thinkfast.robot import fixed_order as fo
from thinkfast.robot.kinematics import Kinematics
from thinkfast.robot.model import CollisionShape, Robot


class Distance(NamedTuple):
    """Smallest distance [m] between checked pairs (0 when touching) and the pair's names."""

    distance: float
    pair: tuple[str, str]


def _geometry(shape: CollisionShape) -> tuple[fcl.CollisionGeometry, np.ndarray, float]:
    """fcl geometry, local bounding-sphere centre (3,) and radius [m] of one primitive."""
    if shape.shape == "box":
        return fcl.Box(*shape.size), np.zeros(3), 0.5 * float(fo.norm(shape.size))
    if shape.shape == "cylinder":
        r, length = shape.size
        return fcl.Cylinder(r, length), np.zeros(3), float(np.hypot(r, 0.5 * length))
    if shape.shape == "sphere":
        return fcl.Sphere(shape.size[0]), np.zeros(3), float(shape.size[0])
    if shape.shape == "mesh":
        import trimesh

        try:
            mesh = trimesh.load(shape.mesh_path, force="mesh")
        except Exception as exc:
            raise RobotModelError(f"{shape.mesh_path}: cannot load mesh ({exc})") from None
        bvh = fcl.BVHModel()
        bvh.beginModel(len(mesh.vertices), len(mesh.faces))
        bvh.addSubModel(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int32))
        bvh.endModel()
        c = mesh.bounding_sphere.primitive.center
        return bvh, np.asarray(c, float), float(mesh.bounding_sphere.primitive.radius)
    raise RobotModelError(f"unsupported collision shape {shape.shape!r}")


class CollisionChecker:
    """Collision queries for one robot in its cell (owns a Kinematics; not thread-safe).

    Args:
        robot: the loaded robot.
        kinematics: FK to share (one is made when omitted).
    """

    def __init__(self, robot: Robot, kinematics: Kinematics | None = None):
        self.robot = robot
        self.kin = kinematics or Kinematics(robot)
        self.names: list[str] = []
        self.links: list[str] = []
        self.objects: list[fcl.CollisionObject] = []
        self.T_link_shape: list[np.ndarray] = []
        centres, radii, moving = [], [], []
        for s in robot.shapes:
            geom, c, r = _geometry(s)
            self._add(s.link, s.link, geom, s.T_link_shape)
            centres.append(c)
            radii.append(r)
            moving.append(s.link != "base_link")
        for s in robot.cell:
            geom, c, r = _geometry(s)
            self._add(s.link, "", geom, s.T_link_shape)
            T = s.T_link_shape  # cell objects are posed in base once
            self.objects[-1].setTransform(fcl.Transform(T[:3, :3], T[:3, 3]))
            centres.append(fo.matvec(T[:3, :3], c) + T[:3, 3])
            radii.append(r)
            moving.append(False)
        self._shape_centre = np.array(centres)  # shape frame (robot) or base (cell)
        self._radius = np.array(radii)
        self._link_ids = [self.kin.frame_id(link) for link in self.links if link]
        self._robot_shapes = [i for i, link in enumerate(self.links) if link]
        self.pairs = self._pairs(moving)
        self._pi = np.array([p[0] for p in self.pairs], dtype=np.int64)
        self._pj = np.array([p[1] for p in self.pairs], dtype=np.int64)
        self._request = fcl.CollisionRequest()
        self._world_centre = self._shape_centre.copy()
        self._drop_rigid_pairs()

    def _add(self, name: str, link: str, geom, T: np.ndarray) -> None:
        self.names.append(name)
        self.links.append(link)
        self.objects.append(fcl.CollisionObject(geom, fcl.Transform()))
        self.T_link_shape.append(np.asarray(T))

    def _pairs(self, moving: list[bool]) -> list[tuple[int, int]]:
        parent = self.robot.link_parent
        allowed = self.robot.allowed_collisions
        pairs = []
        for i in range(len(self.names)):
            for j in range(i + 1, len(self.names)):
                a, b = self.names[i], self.names[j]
                if not (moving[i] or moving[j]) or a == b:
                    continue
                if self.links[i] and self.links[j]:
                    if parent.get(a) == b or parent.get(b) == a:
                        continue
                if frozenset((a, b)) in allowed:
                    continue
                pairs.append((i, j))
        return pairs

    def _rigid_group(self) -> dict[str, str]:
        """Each link mapped to the first link of its group of links joined by fixed joints."""
        fixed = {j.child: j.parent for j in self.robot.chain if j.index < 0 and not j.axis.any()}
        group = {}
        for link in self.robot.link_parent:
            root = link
            while root in fixed:
                root = fixed[root]
            group[link] = root
        return group

    def _drop_rigid_pairs(self) -> None:
        group = self._rigid_group()
        rigid = [
            (i, j)
            for i, j in self.pairs
            if self.links[i] and self.links[j] and group[self.links[i]] == group[self.links[j]]
        ]
        if not rigid:
            return
        self._pose(self.robot.any_q)
        for i, j in rigid:
            if fcl.collide(self.objects[i], self.objects[j], self._request, fcl.CollisionResult()):
                raise RobotModelError(
                    f"{self.robot.urdf_path}: links {self.names[i]!r} and {self.names[j]!r} are "
                    "rigidly attached and overlap: list them in robot.toml allowed_collisions"
                )
        self.pairs = [p for p in self.pairs if p not in rigid]
        self._pi = np.array([p[0] for p in self.pairs], dtype=np.int64)
        self._pj = np.array([p[1] for p in self.pairs], dtype=np.int64)

    def _pose(self, q: np.ndarray) -> None:
        self.kin.update(q)
        oMf = self.kin.data.oMf
        for i in self._robot_shapes:
            M = oMf[self.kin.frame_id(self.links[i])]
            T = fo.matmul(M.homogeneous, self.T_link_shape[i])
            self.objects[i].setTransform(fcl.Transform(T[:3, :3], T[:3, 3]))
            self._world_centre[i] = fo.matvec(T[:3, :3], self._shape_centre[i]) + T[:3, 3]

    def _candidates(self, margin: float) -> np.ndarray:
        d = np.linalg.norm(self._world_centre[self._pi] - self._world_centre[self._pj], axis=1)
        return np.flatnonzero(d <= self._radius[self._pi] + self._radius[self._pj] + margin)

    def in_collision(self, q: np.ndarray) -> bool:
        """True when any checked pair touches at ``q`` [rad] (6,)."""
        self._pose(q)
        for k in self._candidates(0.0):
            result = fcl.CollisionResult()
            if fcl.collide(
                self.objects[self._pi[k]], self.objects[self._pj[k]], self._request, result
            ):
                return True
        return False

    def collisions(self, q: np.ndarray) -> list[tuple[str, str]]:
        """Every checked pair (names) in contact at ``q`` [rad] (6,)."""
        self._pose(q)
        hits = []
        for k in self._candidates(0.0):
            i, j = self._pi[k], self._pj[k]
            if fcl.collide(self.objects[i], self.objects[j], self._request, fcl.CollisionResult()):
                hits.append((self.names[i], self.names[j]))
        return hits

    def min_distance(self, q: np.ndarray) -> Distance:
        """Smallest distance [m] over all checked pairs at ``q`` (0 when touching)."""
        self._pose(q)
        best = Distance(np.inf, ("", ""))
        request = fcl.DistanceRequest()
        for i, j in self.pairs:
            result = fcl.DistanceResult()
            d = max(fcl.distance(self.objects[i], self.objects[j], request, result), 0.0)
            if d < best.distance:
                best = Distance(float(d), (self.names[i], self.names[j]))
        return best
