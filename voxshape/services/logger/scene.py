"""What a recording holds once, static (visible at every time): the viewer's default layout,
the map with its y-up flip, and the styles of each robot's series; the per-step rows carry
only values."""

from __future__ import annotations

import math

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from voxshape.protocol import ACTION_NAMES
from voxshape.world.maps import Box, Cylinder, Map

APPLICATION = "voxshape"
TRAIL_STEPS = 600  # the trails view shows the positions of this many steps before the cursor

WALL = (90, 90, 90)
GOAL = (44, 160, 44, 90)
START = (31, 119, 180)
ROBOT = (214, 39, 40)
SCAN = (255, 127, 14)
TRAIL = (31, 119, 180)
POLICY = (31, 119, 180)
TEACHER = (214, 39, 40)
FEEDBACK = (148, 103, 189)
UTTERANCE = (23, 190, 207)


def blueprint(world: Map | None) -> rrb.Blueprint:
    """The default layout: the map (now, and trails), the text log, and the plots."""
    bounds = None
    if world is not None:  # after the y flip the map spans y in [-height, 0]
        bounds = rrb.VisualBounds2D(
            x_range=[-0.3, world.width + 0.3], y_range=[-world.height - 0.3, 0.3]
        )
    now = rrb.Spatial2DView(name="map", origin="world", visual_bounds=bounds)
    trails = rrb.Spatial2DView(
        name=f"trails ({TRAIL_STEPS} steps)",
        origin="world",
        contents=["+ world/map/static/**", "+ world/map/poses/**"],
        visual_bounds=bounds,
        time_ranges=rrb.VisibleTimeRange(
            "step",
            start=rrb.TimeRangeBoundary.cursor_relative(seq=-TRAIL_STEPS),
            end=rrb.TimeRangeBoundary.cursor_relative(),
        ),
    )
    plots = rrb.Vertical(
        rrb.TimeSeriesView(name="rewards: environment, teacher, feedback", origin="reward"),
        rrb.TimeSeriesView(name="Q-values of the current state", origin="q"),
        rrb.TimeSeriesView(name="episode return (learning curve)", origin="episode/return"),
        rrb.TimeSeriesView(
            name="episode steps and interventions",
            contents=["+ episode/steps/**", "+ episode/interventions/**"],
        ),
        rrb.TimeSeriesView(name="states", origin="states"),
        rrb.TimeSeriesView(name="actions (0 stop 1 fwd 2 back 3 left 4 right)", origin="action"),
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Tabs(now, trails),
                rrb.TextLogView(name="what happened", origin="log"),
                row_shares=[3, 2],
            ),
            plots,
            column_shares=[3, 2],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        # The step timeline, following the newest data: live, the robot as it moves; in a
        # file, where the session ended.
        rrb.TimePanel(state="collapsed", timeline="step", play_state="following"),
    )


def log_map(stream: rr.RecordingStream, m: Map | None) -> None:
    """The y-up flip, then the map: walls and obstacles, goal and start pose."""
    s = stream
    s.log("world/map", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
    if m is None:
        return
    outlines = [
        np.array([*shape.corners(), shape.corners()[0]])
        for shape in m.shapes
        if isinstance(shape, Box)
    ]
    s.log(
        "world/map/static/walls",
        rr.LineStrips2D(outlines, colors=WALL, radii=0.02),
        static=True,
    )
    cylinders = [c for c in m.shapes if isinstance(c, Cylinder)]
    if cylinders:
        s.log(
            "world/map/static/obstacles",
            rr.Ellipses2D(
                centers=[(c.x, c.y) for c in cylinders],
                half_sizes=[(c.radius, c.radius) for c in cylinders],
                colors=WALL,
            ),
            static=True,
        )
    s.log(
        "world/map/static/goal",
        rr.Points2D([(m.goal_x, m.goal_y)], radii=m.goal_radius, colors=GOAL, labels="goal"),
        static=True,
    )
    st = m.start
    s.log(
        "world/map/static/start",
        rr.Arrows2D(
            origins=[(st.x, st.y)],
            vectors=[(0.4 * math.cos(st.theta), 0.4 * math.sin(st.theta))],
            colors=START,
            labels="start",
        ),
        static=True,
    )


def log_robot_styles(stream: rr.RecordingStream, robot: str) -> None:
    """Series styles of a robot's plots, and the colours and sizes of its shapes."""
    s = stream
    lines = {
        f"reward/env/{robot}": (f"R_RL {robot}", (127, 127, 127)),
        f"states/{robot}": (f"states {robot}", POLICY),
        f"td_error/{robot}": (f"TD error {robot}", (127, 127, 127)),
        f"episode/return/{robot}": (f"return {robot}", POLICY),
        f"episode/steps/{robot}": (f"steps {robot}", POLICY),
    }
    for entity, (name, color) in lines.items():
        s.log(entity, rr.SeriesLines(names=name, colors=color), static=True)
    points = {
        f"reward/teacher/{robot}": (f"teacher reward {robot}", TEACHER, "circle"),
        f"reward/feedback/{robot}": (f"feedback arrives {robot}", FEEDBACK, "down"),
        f"reward/utterance/{robot}": (f"utterance {robot}", UTTERANCE, "diamond"),
        f"action/policy/{robot}": (f"policy {robot}", POLICY, "circle"),
        f"action/teacher/{robot}": (f"teacher {robot}", TEACHER, "cross"),
        f"episode/interventions/{robot}": (f"interventions {robot}", TEACHER, "square"),
    }
    for entity, (name, color, marker) in points.items():
        s.log(
            entity,
            rr.SeriesPoints(names=name, colors=color, markers=marker, marker_sizes=3.0),
            static=True,
        )
    s.log(
        f"q/{robot}",
        rr.SeriesLines(names=[f"Q({a}) {robot}" for a in ACTION_NAMES]),
        static=True,
    )
    # Colours and sizes once; the per-step rows carry only positions.
    where = f"world/map/robots/{robot}"
    s.log(f"{where}/scan", rr.Points2D.from_fields(colors=SCAN, radii=0.02), static=True)
    s.log(f"{where}/body", rr.LineStrips2D.from_fields(colors=ROBOT, radii=0.015), static=True)
    s.log(f"{where}/heading", rr.Arrows2D.from_fields(colors=ROBOT, radii=0.02), static=True)
    s.log(
        f"world/map/poses/{robot}",
        rr.Points2D.from_fields(colors=TRAIL, radii=0.03),
        static=True,
    )
