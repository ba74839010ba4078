"""A person dictating an initial trace: commands that hold until the next one, said late, on a
budget, and heard with the recognizer's errors (a pure core, no bus).

The person watches the robot and wants it on the shortest way (`path_command`: "forward" when
facing it, else the turn towards it). Knowing that a word takes effect only once said and
heard, the person judges the pose the robot will have by then if it keeps doing what it does
(a person watching a turning robot says "forward" before it faces the way), and speaks when
that pose needs another command than the one the robot carries out, if:
- no word of theirs is still on its way (said, not yet heard);
- the budget allows: at most `words_per_robot_minute` on average, `words_at_once` at once;
then the word starts after a reaction delay drawn from [delay_min, delay_max] seconds, is said
in `speaking` seconds and heard `recognition` seconds later, wrong with probability `noise`:
the opposite command (the person's slip) or another phrase of the vocabulary (the
recognizer's, as the judging person's words are misheard). A word heard that is not a command
changes nothing; the person sees the robot carry on and says the command again.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field

from voxshape.protocol.vocabulary import Vocabulary
from voxshape.recognition.confusion import MockRecognizer, MockSettings
from voxshape.services.simteacher.teacher import OPPOSITE, Confusion
from voxshape.world.geodesic import way_ahead
from voxshape.world.maps import PASSAGE_RADIUS, Map
from voxshape.world.robot import unicycle

TURNS = ("left", "right")  # carried out for turn_s, then forward
WALL_MARGIN = 0.1  # metres beyond the narrowest passage's radius at which a person sees a wall near


@dataclass(frozen=True)
class DictationProfile:
    """How the person dictates (the module's docstring)."""

    words_per_robot_minute: float = 20.0
    words_at_once: float = 2.0
    delay_min: float = 0.5  # seconds from seeing to the onset of speech, uniform ...
    delay_max: float = 1.5  # ... in [delay_min, delay_max]
    speaking: float = 0.4  # seconds a word takes to say
    recognition: float = 0.3  # seconds from the end of speech to the utterance
    # The heading error (degrees) a person lets the robot drive forward with; a turn word
    # turns the robot for turn_s (the learner's command_steps), then it carries on forward
    keep_forward: float = 30.0
    turn_s: float = 0.75
    wall_ahead_s: float = 0.5  # beyond the word's landing, how far ahead the person looks for walls
    lookahead: float = 1.0  # metres down the way the person aims the robot at
    noise: float = 0.0  # probability a word comes out wrong
    confusion: Confusion = field(default_factory=Confusion)

    def __post_init__(self) -> None:
        if not 0 <= self.delay_min <= self.delay_max:
            raise ValueError("need 0 <= delay_min <= delay_max (seconds)")
        if self.words_per_robot_minute <= 0 or self.words_at_once < 1:
            raise ValueError("need words_per_robot_minute > 0 and words_at_once >= 1")
        if not 0.0 <= self.noise <= 1.0:
            raise ValueError(f"noise {self.noise} is not within [0, 1]")


@dataclass(frozen=True)
class DictatedCommand:
    """A dictated word: what was meant, what is heard (a command, or None), and when."""

    meant: str
    heard: str | None  # the command heard; None: heard as something else, or not at all
    heard_at: float  # robot seconds since the trace began


class DictatingPerson:
    def __init__(
        self,
        m: Map,
        vocabulary: Vocabulary,
        profile: DictationProfile,
        velocities: dict[str, tuple[float, float]],
        seed: int = 0,
    ) -> None:
        self.map, self.profile, self.vocabulary = m, profile, vocabulary
        self.velocities = velocities  # (v, omega) of each command, as the robot carries it out
        self.rng = random.Random(seed)
        self.recognizer = MockRecognizer(
            vocabulary,
            MockSettings(error_rate=1.0, misheard=1.0, dropped=0.0, inserted=0.0, seed=seed),
        )
        self.words = 0  # said so far
        # where the robot would be too near a wall: the person turns it away before it gets there
        self._clear = m.grid.distances_to_goal(PASSAGE_RADIUS + WALL_MARGIN)
        self._tokens, self._counted_at = profile.words_at_once, 0.0
        self._speaking_until = -math.inf
        self._meant: list[tuple[float, str]] = []  # (lands at, command) of words on their way

    def watch(
        self,
        now: float,
        x: float,
        y: float,
        theta: float,
        v: float,
        omega: float,
        doing: str,
        bumped: bool = False,
    ) -> DictatedCommand | None:
        """The robot at robot time `now` (seconds), driving at (v, omega) under the command
        `doing`, and whether it just bumped into something: a word, if the person says one
        now. The person follows their own words on their way: the pose judged is the one the
        robot will have when a word said now lands, carrying out the words already said as
        they land; a robot driving into something is turned towards the way."""
        p = self.profile
        self._meant = [(t, c) for t, c in self._meant if t > now]
        if now < self._speaking_until:
            return None
        lag = (p.delay_min + p.delay_max) / 2 + p.speaking + p.recognition
        pose, doing = (x, y, theta), self._meant[-1][1] if self._meant else doing
        heading_into_wall = False
        for t, (mv, mw) in self._motion(now, v, omega, now + lag + p.wall_ahead_s):
            for _ in range(max(1, math.ceil(t / 0.2))):  # the path, every 0.2 s
                pose = unicycle(*pose, mv, mw, t / max(1, math.ceil(t / 0.2)))
                cell = self.map.grid.cell(*pose[:2])
                heading_into_wall = heading_into_wall or not math.isfinite(self._clear[cell])
        wanted = self._wanted(*pose, doing, bumped or heading_into_wall)
        if wanted is None or (wanted == doing and wanted not in TURNS) or not self._afford(now):
            return None
        onset = now + self.rng.uniform(p.delay_min, p.delay_max)
        self._speaking_until = onset + p.speaking
        heard_at = onset + p.speaking + p.recognition
        self._meant.append((heard_at, wanted))
        self.words += 1
        return DictatedCommand(wanted, self._heard(wanted), heard_at)

    def _motion(
        self, now: float, v: float, omega: float, until: float
    ) -> list[tuple[float, tuple[float, float]]]:
        """(seconds, (v, omega)) pieces of the robot's motion from now until `until`, as the
        person expects it: what it does now, then each word on its way as it lands (a turn
        for `turn_s`, then on forward)."""
        pieces, t, velocity = [], now, (v, omega)
        for lands, command in self._meant:
            if lands >= until:
                break
            pieces.append((lands - t, velocity))
            t, velocity = lands, self.velocities[command]
            if command in TURNS:
                turned = min(until, t + self.profile.turn_s)
                pieces.append((turned - t, velocity))
                t, velocity = turned, self.velocities["forward"]
        pieces.append((until - t, velocity))
        return pieces

    def _wanted(self, x: float, y: float, heading: float, doing: str, bumped: bool) -> str | None:
        """The command the robot should carry out at this pose: a turn towards the way once
        it is more than `keep_forward` off it or about to meet a wall, "forward" when it
        stands facing the way (None: let it carry on)."""
        p = self.profile
        aim = way_ahead(self.map, x, y, p.lookahead)
        if aim is None:
            return None
        way = math.atan2(aim[1] - y, aim[0] - x)
        error = math.degrees(math.remainder(way - heading, math.tau))
        towards = "left" if error > 0 else "right"
        if bumped or abs(error) > p.keep_forward:
            return towards
        if doing != "stop":
            return None
        return towards if self._blocked((x, y, heading), "forward") else "forward"

    def _blocked(self, pose: tuple[float, float, float], command: str) -> bool:
        """Whether the command, carried out for a second from the pose, brings the robot too
        near a wall."""
        v, omega = self.velocities[command]
        for i in range(1, 6):
            x, y, _ = unicycle(*pose, v, omega, 0.2 * i)
            if not math.isfinite(self._clear[self.map.grid.cell(x, y)]):
                return True
        return False

    def _afford(self, now: float) -> bool:
        """Whether the budget has a word left (and spends it); it refills with robot time."""
        p = self.profile
        refill = (now - self._counted_at) * p.words_per_robot_minute / 60
        self._tokens, self._counted_at = min(p.words_at_once, self._tokens + refill), now
        if self._tokens < 1:
            return False
        self._tokens -= 1
        return True

    def _heard(self, command: str) -> str | None:
        """The command as heard: itself, or with probability `noise` the opposite command,
        nothing, or another phrase (None when that is not a command)."""
        p = self.profile
        if self.rng.random() >= p.noise:
            return command
        error = p.confusion.draw(self.rng)
        if error == "wrong_qualifier":
            return OPPOSITE.get(command, command)
        if error == "dropped":
            return None
        phrase = self.vocabulary.meanings[command].phrases["en"][0]
        (wrong,) = self.recognizer.hear(phrase, "en")
        meaning = self.vocabulary.lookup(wrong.text)
        return meaning.action if meaning is not None and meaning.kind == "command" else None
