"""Collision checking of many configurations at once: distance bounds in numpy, fcl where needed.

Every robot primitive is covered by spheres (every point of the primitive lies inside one). For a
checked pair (the pairs of :class:`CollisionChecker`) one side is taken by its sphere cover and the
other exactly (box, cylinder or sphere): the distance from each sphere centre to the exact primitive
minus the sphere radius bounds the pair's distance from below. Only pairs whose bound is <= 0 go to
fcl for the exact answer, so the result is the same as asking fcl about every pair.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import fcl
import numpy as np

from thinkfast.robot.batch_fk import BatchFK
from thinkfast.robot.collision import CollisionChecker
from thinkfast.robot.model import CollisionShape

COVER_EDGE = 0.12  # m: boxes are cut into pieces at most this long (or their thinnest side)


class Hit(NamedTuple):
    """First colliding configuration of a batch: its index and the pair's names."""

    index: int
    pair: tuple[str, str]


def sphere_cover(shape: CollisionShape) -> tuple[np.ndarray, np.ndarray]:
    """Spheres covering a primitive: centres (k, 3) in the shape frame [m] and radii (k,) [m]."""
    if shape.shape == "sphere":
        return np.zeros((1, 3)), np.array([shape.size[0]])
    if shape.shape == "box":
        dims = np.asarray(shape.size, dtype=float)
        edge = max(min(dims.min(), COVER_EDGE), 0.02)
        n = np.maximum(np.ceil(dims / edge - 1e-9).astype(int), 1)
        piece = dims / n
        axes = [(-dims[i] / 2 + piece[i] * (np.arange(n[i]) + 0.5)) for i in range(3)]
        centres = np.array(list(itertools.product(*axes)))
        return centres, np.full(len(centres), 0.5 * np.linalg.norm(piece))
    if shape.shape == "cylinder":
        r, length = shape.size
        if length >= r:  # rod: slices along the axis
            n = int(np.ceil(length / r - 1e-9))
            h = length / (2 * n)
            z = -length / 2 + h * (2 * np.arange(n) + 1)
            return np.column_stack([np.zeros(n), np.zeros(n), z]), np.full(n, np.hypot(r, h))
        # disk: seven circles of radius r/2 (centre + hexagon at sqrt(3)/2 r) cover a disk of r
        ang = np.arange(6) * np.pi / 3
        ring = 0.5 * np.sqrt(3.0) * r
        xy = np.vstack([[0.0, 0.0], np.column_stack([ring * np.cos(ang), ring * np.sin(ang)])])
        rho = np.hypot(0.5 * r * (1 + 1e-9), 0.5 * length)
        return np.column_stack([xy, np.zeros(7)]), np.full(7, rho)
    raise ValueError(f"no sphere cover for {shape.shape!r}")


def point_distance(shape: CollisionShape, p: np.ndarray) -> np.ndarray:
    """Distance [m] (...) from points ``p`` (..., 3) in the shape frame to the primitive (0 inside).

    Meshes are measured to their bounding sphere (a lower bound).
    """
    if shape.shape == "box":
        outside = np.maximum(np.abs(p) - 0.5 * np.asarray(shape.size), 0.0)
        return np.linalg.norm(outside, axis=-1)
    if shape.shape == "cylinder":
        r, length = shape.size
        radial = np.maximum(np.hypot(p[..., 0], p[..., 1]) - r, 0.0)
        axial = np.maximum(np.abs(p[..., 2]) - 0.5 * length, 0.0)
        return np.hypot(radial, axial)
    if shape.shape == "sphere":
        return np.maximum(np.linalg.norm(p, axis=-1) - shape.size[0], 0.0)
    return np.zeros(p.shape[:-1])  # unknown extent: never certifies a pair free


class BatchCollision:
    """Batched exact collision checking for one robot (shares the fcl objects of ``checker``)."""

    def __init__(self, checker: CollisionChecker):
        self.checker = checker
        self.fk = BatchFK(checker.robot)
        self.shapes = list(checker.robot.shapes) + list(checker.robot.cell)
        centres, radii, owner = [], [], []
        for i, link in enumerate(checker.links):
            if not link:
                continue
            c, r = sphere_cover(self.shapes[i])
            T = checker.T_link_shape[i]
            centres.append(c @ T[:3, :3].T + T[:3, 3])  # in the link frame
            radii.append(r)
            owner += [i] * len(r)
        self._centres = np.vstack(centres)
        self._radii = np.concatenate(radii)
        self._owner = np.array(owner)
        self._links = sorted({checker.links[i] for i in set(owner)})
        self._sphere_link = np.array([self._links.index(checker.links[i]) for i in owner])
        # per pair: (sphere indices of the covered side, exact side)
        self._plan = []
        for i, j in checker.pairs:
            a, b = i, j
            if checker.links[j] and self._count(j) < self._count(i):
                a, b = j, i  # cover the side with fewer spheres, measure the other exactly
            self._plan.append((np.flatnonzero(self._owner == a), b))

    def _count(self, i: int) -> int:
        return int(np.count_nonzero(self._owner == i))

    @property
    def link_extent(self) -> dict[str, float]:
        """Per robot link: radius [m] around its frame origin holding all of its spheres."""
        out = {}
        for k, link in enumerate(self._links):
            sel = self._sphere_link == k
            out[link] = float((np.linalg.norm(self._centres[sel], axis=1) + self._radii[sel]).max())
        return out

    def _world_spheres(self, poses: dict[str, np.ndarray]) -> np.ndarray:
        n = len(next(iter(poses.values())))
        out = np.empty((n, len(self._radii), 3))
        for k, link in enumerate(self._links):
            sel = self._sphere_link == k
            P = poses[link]
            out[:, sel] = self._centres[sel] @ P[:, :3, :3].transpose(0, 2, 1) + P[:, None, :3, 3]
        return out

    def _shape_pose(self, b: int, poses: dict[str, np.ndarray]) -> np.ndarray:
        link = self.checker.links[b]
        T = self.checker.T_link_shape[b]
        return poses[link] @ T if link else T[None]

    def lower_bounds(
        self, q: np.ndarray, poses: dict[str, np.ndarray] | None = None
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Distance lower bounds [m] (N, P) for every checked pair, and the link poses used.

        Args:
            q: joint angles [rad] (N, 6).
            poses: link poses for ``q`` when the caller has them already.
        """
        poses = self.fk.link_poses(q) if poses is None else poses
        W = self._world_spheres(poses)
        lb = np.empty((len(W), len(self._plan)))
        shape_pose: dict[int, np.ndarray] = {}
        for p, (spheres, b) in enumerate(self._plan):
            if b not in shape_pose:
                shape_pose[b] = self._shape_pose(b, poses)
            T = shape_pose[b]  # (N or 1, 4, 4)
            local = (W[:, spheres] - T[:, None, :3, 3]) @ T[:, :3, :3]  # R^T (w - t), row-wise
            d = point_distance(self.shapes[b], local) - self._radii[spheres]
            lb[:, p] = d.min(axis=1)
        return lb, poses

    def first_collision(
        self, q: np.ndarray, poses: dict[str, np.ndarray] | None = None
    ) -> Hit | None:
        """The first configuration of ``q`` [rad] (N, 6) in collision, or None when all are free."""
        lb, poses = self.lower_bounds(q, poses)
        rows, cols = np.nonzero(lb <= 0.0)
        ck = self.checker
        for n, p in zip(rows, cols, strict=True):  # row-major: earliest configuration first
            i, j = ck.pairs[p]
            for k in (i, j):
                if ck.links[k]:
                    T = poses[ck.links[k]][n] @ ck.T_link_shape[k]
                    ck.objects[k].setTransform(fcl.Transform(T[:3, :3], T[:3, 3]))
            if fcl.collide(ck.objects[i], ck.objects[j], ck._request, fcl.CollisionResult()):
                return Hit(int(n), (ck.names[i], ck.names[j]))
        return None
