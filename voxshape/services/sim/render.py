"""Top-down pictures of a map: walls, obstacles, start, goal, and optionally a robot's path,
its pose and a laser scan. Maps are drawn y-up, in metres."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: no display needed
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.patches import Circle, FancyArrow, Polygon

from voxshape.services.sim.world import shape_outline
from voxshape.world.maps import Map, Pose
from voxshape.world.robot import RobotModel


def render_map(
    m: Map,
    *,
    trajectory: Sequence[tuple[float, float]] | None = None,
    pose: Pose | None = None,
    scan: np.ndarray | None = None,
    model: RobotModel | None = None,
    path: Path | None = None,
    dpi: int = 100,
) -> np.ndarray:
    """Draws the map; saves a PNG at `path` if given; returns the picture as RGB (h, w, 3)."""
    model = model or RobotModel()
    scale = 6.0 / max(m.width, m.height)
    fig, ax = plt.subplots(figsize=(m.width * scale + 0.4, m.height * scale + 0.6), dpi=dpi)
    try:
        _draw_map(ax, m)
        if trajectory is not None and len(trajectory) > 1:
            xs, ys = zip(*trajectory, strict=True)
            ax.plot(xs, ys, color="#ff7f0e", lw=1.5, label="path")
        if pose is not None:
            _draw_robot(ax, model, pose, scan)
        _frame(ax, m)
        fig.tight_layout()
        if path is not None:
            fig.savefig(path)
        fig.canvas.draw()
        return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    finally:
        plt.close(fig)


def _draw_map(ax: Axes, m: Map) -> None:
    """The walls and obstacles, the goal, and the start pose as an arrow."""
    for shape in m.shapes:
        ax.add_patch(Polygon(shape_outline(shape), closed=True, color="#404040"))
    ax.add_patch(
        Circle((m.goal_x, m.goal_y), m.goal_radius, color="#2ca02c", alpha=0.35, label="goal")
    )
    s = m.start
    ax.add_patch(
        FancyArrow(
            s.x,
            s.y,
            0.4 * math.cos(s.theta),
            0.4 * math.sin(s.theta),
            width=0.06,
            color="#1f77b4",
            label="start",
        )
    )


def _draw_robot(ax: Axes, model: RobotModel, pose: Pose, scan: np.ndarray | None) -> None:
    """The robot's footprint at `pose` and, if given, the points its laser scan hit."""
    ax.add_patch(
        Polygon(
            model.corners(pose.x, pose.y, pose.theta),
            closed=True,
            fill=False,
            color="#d62728",
            lw=1.5,
        )
    )
    if scan is not None:
        a = pose.theta + model.laser_angles()
        lx = pose.x + model.laser_x * math.cos(pose.theta)
        ly = pose.y + model.laser_x * math.sin(pose.theta)
        hit = np.asarray(scan) < model.laser_max
        ax.scatter(
            lx + scan[hit] * np.cos(a[hit]),
            ly + scan[hit] * np.sin(a[hit]),
            s=3,
            color="#d62728",
            label="laser",
        )


def _frame(ax: Axes, m: Map) -> None:
    """The floor with a margin, in metres and to scale, titled with the map's name."""
    ax.set_xlim(-0.2, m.width + 0.2)
    ax.set_ylim(-0.2, m.height + 0.2)
    ax.set_aspect("equal")
    ax.set_title(m.name, fontsize=10)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper left", fontsize=7, framealpha=0.8)
