"""What the page is sent, as JSON: the map and the vocabulary it draws, what every page is
told on joining, and each bus message as the page shows it (its `text` the terminal client's
line, voxshape/teaching/board.py)."""

from __future__ import annotations

import math
import tomllib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from voxshape.protocol import (
    CreditedFeedback,
    EpisodeEvent,
    HelpAnswer,
    HelpRequest,
    Learnt,
    Observation,
    TeachingStats,
    Vocabulary,
)
from voxshape.protocol.vocabulary import LANGUAGES
from voxshape.teaching.board import Board, Shown
from voxshape.world.maps import Box, Map

LASER_FOV = math.pi  # the simulated robot's laser spans this, centred ahead (voxshape/services/sim)


def now_ms(now_s: float) -> float:
    return round(now_s * 1000.0, 3)


def map_json(m: Map) -> dict[str, Any]:
    """The map as the page draws it: walls as centre-line segments [x0, y0, x1, y1] (the border
    included), obstacles as boxes (centre, size, angle in radians, corners) and cylinders."""
    w, h = m.width, m.height
    walls = [[0.0, 0.0, w, 0.0], [w, 0.0, w, h], [w, h, 0.0, h], [0.0, h, 0.0, 0.0]]
    thickness = 0.1
    try:  # the extra walls are in the file as written; the Map holds them as boxes
        data = tomllib.loads(Path(m.source).read_text(encoding="utf-8"))
        walls += [[float(v) for v in wall] for wall in data.get("walls", [])]
        thickness = float(data.get("wall_thickness", thickness))
    except (OSError, tomllib.TOMLDecodeError):
        data = {}
    obstacles = []
    for shape in m.shapes[4 + len(data.get("walls", [])) :]:  # after the border and walls
        if isinstance(shape, Box):
            obstacles.append(
                {
                    "kind": "box",
                    "x": shape.x,
                    "y": shape.y,
                    "width": shape.width,
                    "depth": shape.depth,
                    "angle": shape.angle,
                    "corners": [list(c) for c in shape.corners()],
                }
            )
        else:
            obstacles.append({"kind": "cylinder", "x": shape.x, "y": shape.y, "r": shape.radius})
    return {
        "name": m.name,
        "width": w,
        "height": h,
        "wall_thickness": thickness,
        "walls": walls,
        "obstacles": obstacles,
        "goal": {"x": m.goal_x, "y": m.goal_y, "radius": m.goal_radius},
        "start": {
            "x": m.start.x,
            "y": m.start.y,
            "theta": m.start.theta,
            "jitter": [m.start_jitter.x, m.start_jitter.y, m.start_jitter.theta],
        },
    }


def vocabulary_json(vocabulary: Vocabulary) -> dict[str, list[dict[str, Any]]]:
    """Per language, every phrase with its meaning (the page's word buttons)."""
    out: dict[str, list[dict[str, Any]]] = {language: [] for language in LANGUAGES}
    for meaning in vocabulary.meanings.values():
        for language, phrases in meaning.phrases.items():
            out.setdefault(language, []).extend(
                {
                    "phrase": phrase,
                    "meaning": meaning.name,
                    "kind": meaning.kind,
                    "reward": meaning.reward,
                    "action": meaning.action,
                }
                for phrase in phrases
            )
    return out


@dataclass(frozen=True)
class SessionView:
    """What every page is told on joining, besides the robots (which change)."""

    session: str
    secured: bool
    language: str
    vocabulary: dict[str, list[dict[str, Any]]]
    map: dict[str, Any] | None
    viewer: str | None


_BOARD = Board()  # stateless for episodes and feedback: the terminal client's fields


def obs_json(obs: Observation, at_s: float) -> dict[str, Any]:
    angles = [-LASER_FOV / 2, LASER_FOV / 2]
    if obs.laser:  # beams sit at the centres of equal slices of the field of view
        half = LASER_FOV / len(obs.laser) / 2
        angles = [-LASER_FOV / 2 + half, LASER_FOV / 2 - half]
    return {
        "type": "obs",
        "robot": obs.robot,
        "episode": obs.episode,
        "step": obs.step,
        "episode_step": obs.episode_step,
        "x": round(obs.x, 4),
        "y": round(obs.y, 4),
        "theta": round(obs.theta, 4),
        "laser": [round(r, 3) for r in obs.laser],
        "laser_angles": angles,
        "goal_distance": round(obs.goal_distance, 3),
        "reward": obs.reward,
        "outcome": obs.outcome,
        "collided": obs.collided,
        "stamp": now_ms(at_s),
        "wall_time": now_ms(obs.wall_time),
    }


def episode_json(event: EpisodeEvent) -> dict[str, Any]:
    return {"type": "episode", **_BOARD.episode(event)[0].data}


def feedback_json(feedback: CreditedFeedback) -> dict[str, Any]:
    return {"type": "feedback", **_BOARD.feedback(feedback)[0].data}


def question_json(question: HelpRequest, at_s: float) -> dict[str, Any]:
    """A robot's question; `text` is the terminal's line without its hint."""
    data = _BOARD.question(question)[0].data
    text = data.pop("message")
    return {"type": "question", **data, "text": text, "stamp": now_ms(at_s)}


def answer_json(answer: HelpAnswer) -> dict[str, Any]:
    """Who answered a robot's question, with what: `text` "answered by ana: left"."""
    data = _BOARD.answer(answer)[0].data
    text = data.pop("message")
    return {"type": "answer", **data, "text": text}


def learnt_json(learnt: Learnt) -> dict[str, Any]:
    """A robot has learnt its task: what, in how many episodes and robot minutes."""
    return {
        "type": "learnt",
        "robot": learnt.robot,
        "task": learnt.task,
        "episode": learnt.episode,
        "episodes": learnt.episodes,
        "robot_minutes": round(learnt.robot_seconds / 60, 1),
    }


def stats_json(stats: TeachingStats, teacher: str) -> dict[str, Any]:
    """A robot's teaching statistics as one teacher sees them: its own and the count."""
    own = next((asdict(t) for t in stats.teachers if t.teacher == teacher), None)
    return {
        "type": "stats",
        "robot": stats.robot,
        "episode": stats.episode,
        "final": stats.final,
        "interventions": stats.interventions,
        "teacher": own,
        "teachers": len(stats.teachers),
    }


def notice_json(shown: Shown) -> dict[str, Any]:
    """A Board line (notice or no answer) as the page shows it: `text` is the terminal's."""
    data = shown.data
    return {
        "type": "notice",
        "robot": data.get("robot"),
        "utterance": data.get("utterance"),
        "kind": data["kind"] if shown.event == "notice" else "no_answer",
        "meaning": data.get("meaning"),
        "text": shown.text,
        "heard": data.get("text"),
        "late": bool(data.get("late", False)),
    }
