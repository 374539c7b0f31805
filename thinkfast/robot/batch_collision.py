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

from thinkfast.robot import fixed_order as fo
from thinkfast.robot.batch_fk import BatchFK
from thinkfast.robot.collision import CollisionChecker
from thinkfast.robot.model import CollisionShape

COVER_EDGE = 0.12  # m: boxes are cut into pieces at most this long (or their thinnest side)
CLUSTER = 8  # spheres per cluster of a large cover (the second level of the bounds)


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
        return centres, np.full(len(centres), 0.5 * fo.norm(piece))
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
            centres.append(fo.matmul(c, T[:3, :3].T) + T[:3, 3])  # in the link frame
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
        # per pair, one sphere around the covered side's spheres (in its link frame), then one
        # around each cluster of them: spheres inside a bounding sphere whose bound is positive
        # need no bound of their own (distances to a convex body are 1-Lipschitz)
        self._coarse = []
        for spheres, _ in self._plan:
            link = self._links[self._sphere_link[spheres[0]]]
            parts = _clusters(self._centres, spheres) if len(spheres) > CLUSTER else []
            self._coarse.append(
                (link, self._bounding(spheres), [(c, self._bounding(c)) for c in parts])
            )
        # level 0, all pairs at once: that sphere against one around the exact side
        self._reach = np.array([whole[1] for _, whole, _ in self._coarse])
        mids = {(c[0], c[1][0].tobytes()): c for c in self._coarse}
        self._mids = [(link, mid, np.array([p for p, c in enumerate(self._coarse)
                                            if c[0] == link and np.array_equal(c[1][0], mid)]))
                      for link, (mid, _) in ((c[0], c[1]) for c in mids.values())]  # fmt: skip
        exact = np.array([b for _, b in self._plan])
        self._by_exact = [(b, np.flatnonzero(exact == b)) for b in sorted(set(exact.tolist()))]
        self._level0 = (self._reach + checker._radius[exact] + 1e-9) ** 2

    def _bounding(self, spheres: np.ndarray) -> tuple[np.ndarray, float]:
        """Centre (3,) in the link frame and radius [m] of a sphere holding ``spheres``."""
        c = self._centres[spheres]
        mid = 0.5 * (c.min(axis=0) + c.max(axis=0))
        return mid, float((np.linalg.norm(c - mid, axis=1) + self._radii[spheres]).max())

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
            out[:, sel] = (
                fo.matmul(self._centres[sel], P[:, :3, :3].transpose(0, 2, 1)) + P[:, None, :3, 3]
            )
        return out

    def _shape_pose(self, b: int, poses: dict[str, np.ndarray]) -> np.ndarray:
        link = self.checker.links[b]
        T = self.checker.T_link_shape[b]
        return fo.matmul(poses[link], T) if link else T[None]

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
            # R^T (w - t), row-wise
            local = fo.matmul(W[:, spheres] - T[:, None, :3, 3], T[:, :3, :3])
            d = point_distance(self.shapes[b], local) - self._radii[spheres]
            lb[:, p] = d.min(axis=1)
        return lb, poses

    def suspects(self, poses: dict[str, np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray]:
        """(configuration, pair) indices whose lower bound is <= 0, in row-major order: the same
        as ``np.nonzero(self.lower_bounds(q)[0] <= 0)``, computed sphere by sphere only where
        the pair's bounds at three coarser levels are not positive: a sphere around its covered
        side against one around the exact side, then against the exact shape, then spheres
        around clusters of the covered side's spheres against the exact shape.

        Args:
            poses: link poses (n, 4, 4) in ``base``.
            n: number of configurations.
        """
        shape_pose = {b: self._shape_pose(b, poses) for b, _ in self._by_exact}
        centre = np.empty((n, len(self._plan), 3))
        for link, mid, pairs in self._mids:
            P = poses[link]
            centre[:, pairs] = _points(mid[None], P[:, :3, :3], P[:, :3, 3])
        other = np.empty((n, len(self._plan), 3))
        ck = self.checker
        for b, pairs in self._by_exact:
            c = ck._shape_centre[b]  # in the shape's frame (robot) or in base (cell)
            if ck.links[b]:
                T = shape_pose[b]
                c = _points(c[None], T[:, :3, :3], T[:, :3, 3])
            other[:, pairs] = c
        other -= centre
        np.square(other, out=other)
        near = other.sum(axis=2) <= self._level0
        # level 1: the covered side's sphere against the exact shape
        for p in np.flatnonzero(near.any(axis=0)).tolist():
            b = self._plan[p][1]
            T = shape_pose[b]
            rows = np.flatnonzero(near[:, p])
            Tr = T[rows] if len(T) > 1 else T
            c = centre[rows, p][:, None] - Tr[:, None, :3, 3]
            local = _points(c, Tr[:, :3, :3], inverse=True)[:, 0]
            near[rows, p] = point_distance(self.shapes[b], local) - self._reach[p] <= 1e-9
        rows, cols = [], []
        for p in np.flatnonzero(near.any(axis=0)).tolist():
            (spheres, b), (link, _, parts) = self._plan[p], self._coarse[p]
            T, P, close = shape_pose[b], poses[link], np.flatnonzero(near[:, p])
            if not parts:
                hit = close[self._sphere_bound(P, T, b, spheres, close) <= 0.0]
            else:
                found = np.zeros(n, dtype=bool)
                Pc = P[close]
                Tc = T[close] if len(T) > 1 else T
                mids = np.array([mid for _, (mid, _) in parts])
                c = _points(mids, Pc[:, :3, :3], Pc[:, :3, 3]) - Tc[:, None, :3, 3]
                local = _points(c, Tc[:, :3, :3], inverse=True)  # (rows, clusters, 3)
                reach = np.array([r for _, (_, r) in parts])
                ok = point_distance(self.shapes[b], local) - reach <= 1e-9
                for k in np.flatnonzero(ok.any(axis=0)).tolist():
                    sub = close[ok[:, k]]
                    found[sub[self._sphere_bound(P, T, b, parts[k][0], sub) <= 0.0]] = True
                hit = np.flatnonzero(found)
            rows.append(hit)
            cols.append(np.full(len(hit), p))
        if not rows:
            return np.empty(0, np.intp), np.empty(0, np.intp)
        r, c = np.concatenate(rows), np.concatenate(cols)
        order = np.argsort(r * len(self._plan) + c, kind="stable")
        return r[order], c[order]

    def _sphere_bound(self, P, T, b: int, spheres, rows: np.ndarray) -> np.ndarray:
        """Smallest bound over ``spheres`` (link poses ``P``) against shape ``b`` at ``rows``, as
        :meth:`lower_bounds` computes it."""
        P = P[rows]
        W = fo.matmul(self._centres[spheres], P[:, :3, :3].transpose(0, 2, 1)) + P[:, None, :3, 3]
        T = T[rows] if len(T) > 1 else T
        local = fo.matmul(W - T[:, None, :3, 3], T[:, :3, :3])
        return (point_distance(self.shapes[b], local) - self._radii[spheres]).min(axis=1)

    def first_collisions(
        self, q: np.ndarray, starts: np.ndarray, poses: dict[str, np.ndarray] | None = None
    ) -> list[Hit | None]:
        """:meth:`first_collision` of each of several paths stacked in ``q`` [rad] (N, 6), path
        k starting at ``starts[k]`` (its hit's index counts from there)."""
        poses = self.fk.link_poses(q) if poses is None else poses
        starts = np.asarray(starts, dtype=np.intp)
        rows, cols = self.suspects(poses, len(q))
        path = np.searchsorted(starts, rows, side="right") - 1
        hits: list[Hit | None] = [None] * len(starts)
        ck = self.checker
        for n, p, k in zip(rows.tolist(), cols.tolist(), path.tolist(), strict=True):
            if hits[k] is not None:
                continue
            if self._collide(poses, n, p):
                i, j = ck.pairs[p]
                hits[k] = Hit(n - int(starts[k]), (ck.names[i], ck.names[j]))
        return hits

    def _collide(self, poses: dict[str, np.ndarray], n: int, p: int) -> bool:
        """fcl's exact answer for pair ``p`` at configuration ``n``."""
        ck = self.checker
        i, j = ck.pairs[p]
        for k in (i, j):
            if ck.links[k]:
                T = fo.matmul(poses[ck.links[k]][n], ck.T_link_shape[k])
                ck.objects[k].setTransform(fcl.Transform(T[:3, :3], T[:3, 3]))
        return fcl.collide(ck.objects[i], ck.objects[j], ck._request, fcl.CollisionResult())

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
                    T = fo.matmul(poses[ck.links[k]][n], ck.T_link_shape[k])
                    ck.objects[k].setTransform(fcl.Transform(T[:3, :3], T[:3, 3]))
            if fcl.collide(ck.objects[i], ck.objects[j], ck._request, fcl.CollisionResult()):
                return Hit(int(n), (ck.names[i], ck.names[j]))
        return None


def _clusters(centres: np.ndarray, spheres: np.ndarray) -> list[np.ndarray]:
    """``spheres`` split at the median of their centres' longest extent, until <= CLUSTER."""
    if len(spheres) <= CLUSTER:
        return [spheres]
    c = centres[spheres]
    axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
    order = spheres[np.argsort(c[:, axis], kind="stable")]
    half = len(order) // 2
    return _clusters(centres, order[:half]) + _clusters(centres, order[half:])


def _points(p: np.ndarray, R: np.ndarray, t: np.ndarray | None = None, inverse: bool = False):
    """Points ``p`` (K, 3) or (N, K, 3) mapped by rotations ``R`` (N, 3, 3) (and origins ``t``
    (N, 3)): ``R p + t``, or ``R^T p`` with ``inverse``; (N, K, 3). For the bounds' first
    levels only (not bit for bit a matmul)."""
    if p.ndim == 2:
        p = p[None]
    if inverse:
        out = p[..., 0:1] * R[:, None, 0, :] + p[..., 1:2] * R[:, None, 1, :]
        out += p[..., 2:3] * R[:, None, 2, :]
    else:
        out = p[..., 0][..., None] * R[:, None, :, 0] + p[..., 1][..., None] * R[:, None, :, 1]
        out += p[..., 2][..., None] * R[:, None, :, 2]
    if t is not None:
        out += t[:, None, :]
    return out
