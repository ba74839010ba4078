"""What `voxshape teach` shows at the terminal: its lines (text, or JSON with --json), the
status board in this client's words, and each event of the bus shown on it."""

from __future__ import annotations

import json
import time

from voxshape.protocol import (
    CreditedFeedback,
    EpisodeEvent,
    HelpAnswer,
    HelpRequest,
    Observation,
    TeacherNotice,
    Utterance,
    Vocabulary,
)
from voxshape.runtime import BusConfig, Input, Presence
from voxshape.teaching.board import ANSWER_WITHIN_S, Board, Shown, SpeechWatch

BELL = "\a"  # rung with a robot's question (text mode only: --json stays clean)


class Screen:
    def __init__(self, as_json: bool) -> None:
        self.as_json = as_json

    def show(self, items: list[Shown]) -> None:
        for item in items:
            if self.as_json:
                line = json.dumps(item.as_json())
            else:
                line = (BELL if item.event == "question" else "") + item.text
            print(line, flush=True)

    def note(self, event: str, message: str, **data: object) -> None:
        self.show([Shown(event, message, {"message": message, **data})])


def ask_hint(vocabulary: Vocabulary, language: str) -> str:
    """What to answer a robot's question with, in the teacher's words: "say left, right or
    forward" (its language's first phrase of each; English, else the action, without)."""

    def phrase(action: str) -> str:
        for meaning in vocabulary.meanings.values():
            if meaning.kind == "command" and meaning.action == action:
                phrases = meaning.phrases.get(language) or meaning.phrases.get("en")
                return phrases[0] if phrases else action
        return action

    left, right, forward = (phrase(a) for a in ("left", "right", "forward"))
    return f"say {left}, {right} or {forward}"


def terminal_board(
    bus: BusConfig, teacher: str, robot: str, every: float, screen: Screen, ask: str = ""
) -> Board:
    """The status board, with what it says when nothing answers (and to a robot's question:
    `ask`); warns at once of a --teacher that a secured router would silence."""
    session = bus.session
    hint = f"no arbiter in session {session!r} heard it (`voxshape status --session {session}`)"
    if bus.user is not None and bus.user != teacher:
        refused = (
            f"a secured router lets user {bus.user!r} speak only as teacher {bus.user!r}: it "
            f"drops the words of teacher {teacher!r} (leave --teacher out: it defaults to --user)"
        )
        screen.note("warning", refused)
        hint = f"{hint}, or {refused}"
    return Board(
        every,
        ANSWER_WITHIN_S,
        hint,
        robot_missing=f"robot {robot!r} is not running in session {session!r}: nothing seen of "
        f"it within {ANSWER_WITHIN_S:g} s (`voxshape status --session {session}` lists robots)",
        started_at=time.monotonic(),
        ask_hint=ask,
    )


def show_event(event: object, speech: SpeechWatch, board: Board, screen: Screen) -> None:
    """Shows what `event` (one of the node's, or None) changed, then what time brought."""
    now = time.monotonic()
    match event:
        case Presence(role="speech", node=node, alive=alive):
            screen.show(speech.change(node, alive))
        case Input(message=Utterance() as utterance):
            screen.show(board.recognized(utterance, now))
        case Input(message=Observation() as obs):
            screen.show(board.observation(obs, now))
        case Input(message=EpisodeEvent() as episode):
            screen.show(board.episode(episode))
        case Input(message=CreditedFeedback() as feedback):
            screen.show(board.feedback(feedback))
        case Input(message=TeacherNotice() as notice):
            screen.show(board.notice(notice, now))
        case Input(message=HelpRequest() as question):
            screen.show(board.question(question))
        case Input(message=HelpAnswer() as answer):
            screen.show(board.answer(answer))
    screen.show(board.tick(now))
