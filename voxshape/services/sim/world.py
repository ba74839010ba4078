"""The PyBullet world: walls and obstacles as one static mesh, robots driven kinematically.

Each control step integrates the unicycle model exactly over a few sub-steps, teleports the
robot's body and asks PyBullet for contacts after each one; on contact the robot stays at its
last free pose. This is exact (no motor lag) and the fastest drive measured (FIELD-NOTES:
kinematic ~2500 steps/s, base velocity ~1650, wheel URDF ~600 with a 0.2 s lag). There is no
hidden physics state: a pose is all there is to a robot, and a reset is one teleport,
bit-identical every time (no saveState/restoreState needed, nor its ~156 KB per state).

PyBullet is asked about contacts only near something: at a pose more than `SURELY_FREE` from
touching anything (the map's clearance grid, else the footprint's exact clearance from the
walls and obstacles, compiled in `planar.py`; and the other robots) the robot moves without
a query. The first such pose after a query is still asked once, which empties PyBullet's
contact cache as asking at every step would: the runs are the same, step for step, as with
a query at every sub-step (`cull=False`).
"""

from __future__ import annotations

import math
import os
import sys

import numpy as np

from voxshape.world.maps import Box, Map, Pose
from voxshape.world.robot import RobotModel, unicycle

# `import pybullet` prints "pybullet build time: ..." from C (measured here: on stderr);
# keep it out of every service's log.
sys.stderr.flush()
_saved, _devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
os.dup2(_devnull, 2)
try:
    import pybullet as pb
finally:
    os.dup2(_saved, 2)
    os.close(_saved)
    os.close(_devnull)

BODY_HEIGHT = 0.25  # the robot's box, centred at SENSOR_HEIGHT
SENSOR_HEIGHT = 0.2
CYLINDER_SIDES = 32
ALL_GROUPS = (1 << 30) - 1
MAX_ROBOTS = 28  # one collision-group bit each, above the two PyBullet uses
RECOIL_STEP = 0.02  # metres: the bumper reflex checks for contact this often as it backs off
# Clearance (metres) beyond the circumradius past which a pose cannot touch anything: more
# than PyBullet's contact threshold (0.02) and the cylinders' polygons' excess (< 0.01).
SURELY_FREE = 0.1


def _add_prism(
    outline: list[tuple[float, float]],
    height: float,
    vertices: list[list[float]],
    indices: list[int],
) -> None:
    """Appends a closed vertical prism over a convex counter-clockwise outline."""
    base, n = len(vertices), len(outline)
    vertices += [[x, y, 0.0] for x, y in outline] + [[x, y, height] for x, y in outline]
    for i in range(n):
        j = (i + 1) % n
        indices += [base + i, base + j, base + n + j, base + i, base + n + j, base + n + i]
    for i in range(1, n - 1):  # bottom (facing down) and top (facing up) fans
        indices += [base, base + i + 1, base + i, base + n, base + n + i, base + n + i + 1]


def shape_outline(shape: object) -> list[tuple[float, float]]:
    """A shape's outline, counter-clockwise; a cylinder as a polygon whose sides touch the
    circle (so the collision body is never thinner than the circle, and at most 0.5% wider)."""
    if isinstance(shape, Box):
        return shape.corners()
    r = shape.radius / math.cos(math.pi / CYLINDER_SIDES)
    return [
        (shape.x + r * math.cos(a), shape.y + r * math.sin(a))
        for a in np.linspace(0, math.tau, CYLINDER_SIDES, endpoint=False)
    ]


class World:
    """One PyBullet client with a map's walls and `n_robots` robot bodies."""

    def __init__(
        self,
        m: Map,
        n_robots: int,
        model: RobotModel | None = None,
        substeps: int = 4,
        cull: bool = True,
    ) -> None:
        if not 1 <= n_robots <= MAX_ROBOTS:
            raise ValueError(f"a world holds 1 to {MAX_ROBOTS} robots, not {n_robots}")
        self.map = m
        self.model = model or RobotModel()
        self.substeps = substeps
        self.client = pb.connect(pb.DIRECT)
        c = self.client
        pb.setPhysicsEngineParameter(deterministicOverlappingPairs=1, physicsClientId=c)
        pb.setGravity(0, 0, 0, physicsClientId=c)
        self.walls = self._build_walls(m)
        half = [self.model.length / 2, self.model.width / 2, BODY_HEIGHT / 2]
        shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=c)
        self.bodies = []
        for i in range(n_robots):
            # mass > 0: a mass-0 body gets no contacts with static walls (FIELD-NOTES). Own
            # collision groups: the default ones made contact and ray queries 2x slower.
            body = pb.createMultiBody(
                1.0, shape, basePosition=[-10.0 - 2 * i, -10.0, SENSOR_HEIGHT], physicsClientId=c
            )
            pb.setCollisionFilterGroupMask(body, -1, 1 << (i + 2), ALL_GROUPS, physicsClientId=c)
            self.bodies.append(body)
        self.poses = [Pose(-10.0 - 2 * i, -10.0, 0.0) for i in range(n_robots)]
        self.cull = cull
        if cull:
            from voxshape.services.sim.planar import footprint_clearance  # numba: only where culled

            self._footprint_clearance = footprint_clearance
            self._outlines = m.outlines()
        self._settled = [False] * n_robots  # asked at a free pose since the last contact
        self._stale: set[int] = set()  # robots moved without their body being placed

    def _build_walls(self, m: Map) -> int:
        """Every wall and obstacle in one static triangle mesh: one body (FIELD-NOTES)."""
        vertices: list[list[float]] = []
        indices: list[int] = []
        for shape in m.shapes:
            _add_prism(shape_outline(shape), m.wall_height, vertices, indices)
        mesh = pb.createCollisionShape(
            pb.GEOM_MESH, vertices=vertices, indices=indices, physicsClientId=self.client
        )
        return pb.createMultiBody(0, mesh, physicsClientId=self.client)

    def place(self, i: int, pose: Pose) -> None:
        self._settled[i] = False
        self._place_body(i, pose)

    def _place_body(self, i: int, pose: Pose) -> None:
        pb.resetBasePositionAndOrientation(
            self.bodies[i],
            [pose.x, pose.y, SENSOR_HEIGHT],
            (0.0, 0.0, math.sin(pose.theta / 2), math.cos(pose.theta / 2)),
            physicsClientId=self.client,
        )
        self.poses[i] = pose
        self._stale.discard(i)

    def in_contact(self, i: int) -> bool:
        for j in list(self._stale):  # every body where it is, before PyBullet is asked
            self._place_body(j, self.poses[j])
        pb.performCollisionDetection(physicsClientId=self.client)
        contacts = pb.getContactPoints(bodyA=self.bodies[i], physicsClientId=self.client)
        return any(c[8] < 0.0 for c in contacts)  # c[8]: contact distance, < 0 = overlap

    def move(self, i: int, v: float, omega: float, dt: float) -> bool:
        """Drives robot i at (v, omega) for dt seconds; True if it hit something: it then
        stops at its last free pose and its bumper reflex backs it off (`recoil`)."""
        h = dt / self.substeps
        p = self.poses[i]
        x, y, theta = p.x, p.y, p.theta
        # Free by more than any point of it moves (|v| dt, and R |omega| dt turning): no
        # sub-step can touch.
        reach = (abs(v) + self.model.circumradius * abs(omega)) * dt
        if self.cull and self._settled[i] and self._surely_free(i, p, reach):
            for _ in range(self.substeps):
                x, y, theta = unicycle(x, y, theta, v, omega, h)
            self.poses[i] = Pose(x, y, theta)
            self._stale.add(i)
            return False
        for _ in range(self.substeps):
            x, y, theta = unicycle(x, y, theta, v, omega, h)
            if not self._try(i, Pose(x, y, theta)):
                self.recoil(i, -1.0 if v >= 0 else 1.0)
                return True
        return False

    def recoil(self, i: int, direction: float) -> None:
        """The bumper reflex: the model's `recoil` metres straight back from a bump (forward
        after a bump while reversing), as far as it is free. A box pressed squarely to a wall
        cannot turn either way (a corner would enter the wall): without it the robot is
        pinned there."""
        steps = max(1, round(self.model.recoil / RECOIL_STEP))
        d = direction * self.model.recoil / steps
        for _ in range(steps):
            p = self.poses[i]
            if not self._try(
                i, Pose(p.x + d * math.cos(p.theta), p.y + d * math.sin(p.theta), p.theta)
            ):
                return

    def _try(self, i: int, pose: Pose) -> bool:
        """Places robot i at `pose` if it is free there; else leaves it where it was."""
        free = self.cull and self._surely_free(i, pose)
        if free and self._settled[i]:
            self.poses[i] = pose
            self._stale.add(i)
            return True
        before = self.poses[i]
        self._place_body(i, pose)
        if self.in_contact(i):
            self._place_body(i, before)
            self._settled[i] = False
            return False
        self._settled[i] = free
        return True

    def _surely_free(self, i: int, pose: Pose, margin: float = 0.0) -> bool:
        """Whether robot i at `pose` is more than SURELY_FREE (plus `margin`) metres from
        touching anything: the map's clearance grid, else its footprint's exact clearance,
        and the other robots' circles."""
        free, m = SURELY_FREE + margin, self.model
        if self.map.grid.clearance_bound(pose.x, pose.y) <= m.circumradius + free:
            clearance = self._footprint_clearance(
                pose.x, pose.y, pose.theta, m.length / 2, m.width / 2, *self._outlines
            )
            if clearance <= free:
                return False
        return all(
            math.hypot(p.x - pose.x, p.y - pose.y) > 2 * m.circumradius + free
            for j, p in enumerate(self.poses)
            if j != i
        )

    def close(self) -> None:
        if self.client is not None and pb.isConnected(self.client):
            pb.disconnect(self.client)
        self.client = None
