"""Messages -> rerun: what a session looks like in the viewer.

Entities (`<r>` a robot, `<t>` a teacher):

    world/map                      y-up flip (rerun's 2D views are y-down)
    world/map/static/...           walls and obstacles, goal, start pose
    world/map/robots/<r>/body      footprint outline   (per step; thinned when behind)
    world/map/robots/<r>/scan      laser hits          (per step; thinned when behind)
    world/map/robots/<r>/heading   heading arrow       (per step)
    world/map/poses/<r>            position            (per step; the "trails" view)
    reward/env/<r>                 R_RL per step
    reward/teacher/<r>             teacher reward x weight, at each credited step
    reward/feedback/<r>            marker where credited feedback arrived (value: its reward)
    reward/utterance/<r>           marker where an utterance arrived
    action/policy/<r>, action/teacher/<r>   the discrete action taken, by who chose it
    q/<r>                          Q-values of the current state, one series per action
    states/<r>, td_error/<r>       number of states, TD error
    episode/return/<r>, episode/steps/<r>   the learning curve, at each episode's end
    episode/interventions/<r>      the arbiter's final count of an episode's interventions
                                   (TeachingStats, as the report counts), at the episode's end
    log/<r>, log/teachers/<t>, log/session   text: episodes, utterances, feedback, presence

Timelines: `step` (the robot's global step), `episode`, `sim_time` and `wall_time` (when the
logger received the message; messages without a robot have only `wall_time`).
Per-step data is buffered and sent as columns (`flush`; columns.py), 5-20x cheaper than one
call per item. What is logged once, static (the viewer's layout, the map, the series' styles),
is scene.py's.
No bus here: the same code renders live (following the event log) and in replays.
"""

from __future__ import annotations

import logging
import math
from collections import Counter

import numpy as np
import rerun as rr

from voxshape.protocol import (
    Action,
    AudioChunk,
    CreditedFeedback,
    EpisodeEvent,
    LearningSummary,
    Message,
    Observation,
    TeachingStats,
    Utterance,
    to_wire,
)
from voxshape.runtime import worth_logging
from voxshape.services.logger.columns import Columns, When, set_time
from voxshape.services.logger.decoding import Decoded, Gap, Known, PresenceChange, Rejected, Unknown
from voxshape.services.logger.scene import log_map, log_robot_styles
from voxshape.services.logger.tally import RobotTally, SessionTally
from voxshape.world.maps import Map
from voxshape.world.robot import RobotModel

log = logging.getLogger("voxshape.services.logger")

GOAL_MISMATCH_M = 0.05  # the map's goal and the one observations imply may differ this much
ENDS_KEPT = 256  # episode ends remembered, to draw their final interventions when they come
TEXT_PREVIEW = 160


class Recorder:
    """Renders decoded event-log records into a rerun RecordingStream.

    `record(decoded, detail=False)` skips the per-step visual detail (scan, footprint) of an
    observation: what a logger that fell behind leaves out. Everything else is always drawn.
    """

    def __init__(self, stream: rr.RecordingStream, world: Map | None) -> None:
        self.stream = stream
        self.world = world
        self.model = RobotModel()
        self.tally = SessionTally()
        self.counters: Counter[str] = Counter()
        self._columns = Columns()
        self._robots: set[str] = set()
        self._goal_checked: set[str] = set()
        self._ends: dict[tuple[str, int], When] = {}  # (robot, episode) -> when it ended
        self.counters["thinned_scans"] = 0  # always reported, even when nothing was thinned

    # -- static --------------------------------------------------------------------------
    def start(self) -> None:
        """Logs the map and the y-up flip (static: visible at every time)."""
        log_map(self.stream, self.world)

    def _new_robot(self, robot: str) -> None:
        """A robot's series styles (static), once."""
        self._robots.add(robot)
        log_robot_styles(self.stream, robot)

    # -- records -------------------------------------------------------------------------
    def record(self, decoded: Decoded, *, detail: bool = True) -> None:
        """Draws one record. One that cannot be drawn (a bug here) is counted and logged,
        and the recording goes on: a run stays renderable whatever one record holds."""
        self.tally.observe(decoded)
        self.counters["records"] += 1
        try:
            self._record(decoded, detail)
        except Exception:
            self.counters["not_drawn"] += 1
            if worth_logging(self.counters["not_drawn"]):
                log.exception(
                    "a record could not be drawn (%d so far): %s", self.counters["not_drawn"],
                    decoded.record.key,
                )  # fmt: skip

    def _record(self, decoded: Decoded, detail: bool) -> None:
        match decoded:
            case Known(message=message):
                self.counters[f"messages.{message.TYPE}"] += 1
                robot = getattr(message, "robot", None)
                if isinstance(robot, str) and robot not in self._robots:
                    self._new_robot(robot)
                self._message(decoded, message, detail)
            case PresenceChange(role=role, node=node, alive=alive):
                self.counters["presence"] += 1
                verb = "joined" if alive else "left"
                self._text(decoded, "log/session", f"{role} {node} {verb} the session", "DEBUG")
            case Gap(missed=missed):
                self.counters["missed"] += missed
                self._text(
                    decoded,
                    "log/session",
                    f"the logger missed {missed} message(s) on {decoded.record.key}: it was "
                    "stopped for longer than their publisher keeps them",
                    "WARN",
                )
            case Unknown(type_name=type_name, fields=fields):
                self.counters["unknown_types"] += 1
                body = _preview(fields)
                self._text(
                    decoded, "log/session", f"{type_name} on {decoded.record.key}: {body}", "INFO"
                )
            case Rejected(problem=problem):
                self.counters["rejected"] += 1
                n = self.counters["rejected"]
                if worth_logging(n):
                    self._text(
                        decoded,
                        "log/session",
                        f"rejected #{n} on {decoded.record.key}: {problem}",
                        "WARN",
                    )

    def _message(self, decoded: Known, message: Message, detail: bool) -> None:
        match message:
            case Observation():
                self._observation(decoded, message, detail)
            case Action():
                when = self._when_step(message.robot, message.step, decoded)
                if message.discrete is not None:
                    self._row(
                        f"action/{message.chooser}/{message.robot}",
                        "scalar",
                        when,
                        float(message.discrete),
                    )
            case LearningSummary():
                when = self._when_step(message.robot, message.step, decoded)
                if message.q_values:
                    self._row(f"q/{message.robot}", "scalars", when, message.q_values)
                self._row(f"states/{message.robot}", "scalar", when, float(message.states))
                self._row(f"td_error/{message.robot}", "scalar", when, message.td_error)
            case EpisodeEvent():
                self._episode(decoded, message)
            case TeachingStats():
                self._teaching(decoded, message)
            case CreditedFeedback():
                self._feedback(decoded, message)
            case Utterance():
                self._utterance(decoded, message)
            case AudioChunk():
                if message.final:  # chunks are many: one line per stream, at its end
                    self._text(
                        decoded,
                        f"log/teachers/{message.teacher}",
                        f"{message.teacher}: audio stream {message.stream} ended "
                        f"({message.seq + 1} chunks)",
                        "DEBUG",
                        robot=message.robot,
                    )
            case _:  # a type added to the protocol after this renderer: shown as text
                wire = to_wire(message)
                body = _preview({k: v for k, v in wire.items() if k not in ("schema", "type")})
                self._text(
                    decoded,
                    "log/session",
                    f"{message.TYPE}: {body}",
                    "INFO",
                    robot=getattr(message, "robot", None),
                )

    def _observation(self, decoded: Known, obs: Observation, detail: bool) -> None:
        r = obs.robot
        when = When(obs.step, obs.episode, obs.sim_time, decoded.record.received)
        self._row(f"world/map/poses/{r}", "point", when, (obs.x, obs.y))
        c, s = math.cos(obs.theta), math.sin(obs.theta)
        self._row(
            f"world/map/robots/{r}/heading", "arrow", when, ((obs.x, obs.y), (0.35 * c, 0.35 * s))
        )
        self._row(f"reward/env/{r}", "scalar", when, obs.reward)
        if detail:
            corners = self.model.corners(obs.x, obs.y, obs.theta)
            self._row(
                f"world/map/robots/{r}/body", "strip", when, np.vstack([corners, corners[:1]])
            )
            self._row(f"world/map/robots/{r}/scan", "points", when, self._scan_points(obs))
        else:
            self.counters["thinned_scans"] += 1
        if r not in self._goal_checked:
            self._goal_checked.add(r)
            self._check_goal(decoded, obs)

    def _scan_points(self, obs: Observation) -> np.ndarray:
        ranges = np.asarray(obs.laser, dtype=np.float64)
        if len(ranges) == 0:
            return np.zeros((0, 2))
        model = self.model
        step = model.laser_fov / len(ranges)
        angles = obs.theta - model.laser_fov / 2 + step * (np.arange(len(ranges)) + 0.5)
        hit = ranges < model.laser_max - 1e-6
        lx = obs.x + model.laser_x * math.cos(obs.theta)
        ly = obs.y + model.laser_x * math.sin(obs.theta)
        return np.column_stack(
            [lx + ranges[hit] * np.cos(angles[hit]), ly + ranges[hit] * np.sin(angles[hit])]
        )

    def _check_goal(self, decoded: Known, obs: Observation) -> None:
        """The first observation says where the simulator's goal is: does the map agree?"""
        if self.world is None:
            return
        a = obs.theta + obs.goal_bearing
        gx, gy = obs.x + obs.goal_distance * math.cos(a), obs.y + obs.goal_distance * math.sin(a)
        off = math.hypot(gx - self.world.goal_x, gy - self.world.goal_y)
        if off > GOAL_MISMATCH_M:
            self.counters["map_mismatch"] += 1
            text = (
                f"the simulator's goal for robot {obs.robot} is at ({gx:.2f}, {gy:.2f}), "
                f"{off:.2f} m from the goal of the map drawn ({self.world.name}): give the "
                "logger the simulator's --task"
            )
            log.warning(text)
            self._text(decoded, f"log/{obs.robot}", text, "WARN", robot=obs.robot)

    def _episode(self, decoded: Known, event: EpisodeEvent) -> None:
        r = event.robot
        when = When(event.step, event.episode, event.sim_time, decoded.record.received)
        if event.kind == "start":
            self._text(decoded, f"log/{r}", f"episode {event.episode} starts", "DEBUG", when=when)
            return
        self._set_time(when, decoded.record.received)
        self.stream.log(f"episode/return/{r}", rr.Scalars(event.env_return))
        self.stream.log(f"episode/steps/{r}", rr.Scalars(float(event.episode_steps)))
        self._ends.pop((r, event.episode), None)  # a restarted simulator's: the latest wins
        self._ends[(r, event.episode)] = when
        if len(self._ends) > ENDS_KEPT:
            del self._ends[next(iter(self._ends))]
        self._text(
            decoded,
            f"log/{r}",
            f"episode {event.episode} ends: {event.kind} after {event.episode_steps} steps, "
            f"return {event.env_return:+g}",
            "INFO",
            when=when,
        )

    def _teaching(self, decoded: Known, stats: TeachingStats) -> None:
        """An episode's interventions once the arbiter's count is final (a few seconds after
        it ended), drawn at its end: the count of the report and the demo's table."""
        when = self._ends.get((stats.robot, stats.episode))
        if not stats.final or when is None:
            return
        self._set_time(when, decoded.record.received)
        self.stream.log(
            f"episode/interventions/{stats.robot}", rr.Scalars(float(stats.interventions))
        )
        self._text(
            decoded,
            f"log/{stats.robot}",
            f"episode {stats.episode}: {stats.interventions} intervention(s), the arbiter's "
            "final count",
            "INFO",
            when=when,
        )

    def _feedback(self, decoded: Known, feedback: CreditedFeedback) -> None:
        r = feedback.robot
        tally = self.tally.robot(r)
        steps = [c.step for c in feedback.credits]
        span = f"step {steps[0]}" if len(steps) == 1 else f"steps {min(steps)}-{max(steps)}"
        who = ", ".join(feedback.teachers)
        if feedback.kind == "reward":
            what = f"reward {feedback.reward:+g}"
            for credit in feedback.credits:
                past = tally.time_of(credit.step)
                when = When(
                    credit.step,
                    past.episode if past else tally.episode,
                    past.sim_time if past else tally.sim_time,
                    past.wall_time if past else decoded.record.received,
                )
                self._set_time(when, decoded.record.received)
                self.stream.log(f"reward/teacher/{r}", rr.Scalars(feedback.reward * credit.weight))
        else:
            what = f"command {feedback.command}"
        now = self._when_now(tally, decoded)
        self._set_time(now, decoded.record.received)
        self.stream.log(f"reward/feedback/{r}", rr.Scalars(feedback.reward or 0.0))
        self._text(decoded, f"log/{r}", f"{who}: {what}, credited to {span}", "INFO", when=now)

    def _utterance(self, decoded: Known, utterance: Utterance) -> None:
        tally = self.tally.robot(utterance.robot)
        now = self._when_now(tally, decoded)
        self._set_time(now, decoded.record.received)
        self.stream.log(f"reward/utterance/{utterance.robot}", rr.Scalars(0.0))
        self._text(
            decoded,
            f"log/teachers/{utterance.teacher}",
            f"{utterance.teacher} to {utterance.robot}: {utterance.text!r} "
            f"({utterance.confidence:.2f}, {utterance.language}, {utterance.engine})",
            "INFO",
            when=now,
        )

    # -- time and output -----------------------------------------------------------------
    def _when_step(self, robot: str, step: int, decoded: Decoded) -> When:
        tally = self.tally.robot(robot)
        past = tally.time_of(step)
        if past is not None:
            return When(step, past.episode, past.sim_time, decoded.record.received)
        return When(step, tally.episode, tally.sim_time, decoded.record.received)

    @staticmethod
    def _when_now(tally: RobotTally, decoded: Decoded) -> When | None:
        """The robot's latest step, or None before its first observation."""
        if tally.step is None:
            return None
        return When(tally.step, tally.episode, tally.sim_time, decoded.record.received)

    def _set_time(self, when: When | None, wall_time: float) -> None:
        """`when` on every timeline, or (before a robot's first step, or a robot never seen:
        a word said to it) `wall_time` alone."""
        set_time(self.stream, when, wall_time)

    def _text(
        self,
        decoded: Decoded,
        entity: str,
        text: str,
        level: str,
        *,
        robot: str | None = None,
        when: When | None = None,
    ) -> None:
        if when is None and robot is not None:
            when = self._when_now(self.tally.robot(robot), decoded)
        self._set_time(when, decoded.record.received)
        self.stream.log(entity, rr.TextLog(text, level=level))

    def _row(self, entity: str, kind: str, when: When, value: object) -> None:
        self._columns.add(entity, kind, when, value)

    @property
    def pending_rows(self) -> int:
        return self._columns.pending_rows

    def flush(self) -> None:
        """Sends the buffered per-step rows as columns."""
        self._columns.send(self.stream)


def _preview(fields: dict) -> str:
    parts = []
    for k, v in fields.items():
        if k in ("id", "sent_at"):
            continue
        if isinstance(v, bytes):
            text = f"<{len(v)} bytes>"
        elif isinstance(v, list | tuple) and len(v) > 6:
            text = f"[{len(v)} values]"
        else:
            text = str(v)
        parts.append(f"{k}={text}")
    body = ", ".join(parts)
    return body if len(body) <= TEXT_PREVIEW else body[: TEXT_PREVIEW - 3] + "..."
