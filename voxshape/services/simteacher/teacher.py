"""The simulated teacher's pure core: a scripted person for experiments and tests (no bus).

It knows the map's true geodesic distance to the goal (a grid search around walls and
obstacles, never the straight line) and watches the robot:

- every `interval` seconds of robot time it compares the distance now with the distance at
  its previous look: progress of at least `small_change` metres is "good", of at least
  `large_change` "excellent"; regress the same way is "bad" or "terrible"; a smaller change
  (turning on the spot, or a standstill) gets no comment, unless the robot has made no
  progress for `stuck_after` seconds (pinned to a wall, or turning back and forth): then it is
  "bad" at every look until it gets going again, as a person watching would say;
- a bump (the first step of a run of collided steps) is "terrible", the goal is "goal";
- it does not always speak: the chance it comments on what it saw follows a
  `FeedbackSchedule` (the paper's teacher: permanent during the first episodes and sporadic
  later), and a person's budget (`rate`) and eye for salient moments (`salient`) leave most
  looks unsaid: `PERSON`, the default, says at most 4 words a robot minute, where the
  `TIRELESS` teacher of earlier experiments said about 50;
- it leans to praise with `positive_bias`: that share of its scolding is left unsaid;
- it errs with probability `noise`, the kind of error drawn by the `Confusion` weights: a
  wrong qualifier (the opposite judgement of the same strength, its own slip) or a misheard
  word (what the mock speech engine's confusion core, voxshape/services/speech/mock.py, makes of it:
  another phrase of the vocabulary, a command included, with its lower confidence);
- it reacts late: speech starts `delay` seconds (Gaussian, `jitter`, never negative) after
  what it judges was displayed.

It also dictates initial traces: the command that follows the shortest path from a pose
("forward" when facing downhill on the geodesic distance, else the turn towards it).

Words come from the vocabulary only (voxshape/protocol/vocabulary.toml): the teacher names a meaning
and says its first English phrase. Seeded: the same seed and readings give the same words.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field

from voxshape.protocol.vocabulary import Vocabulary
from voxshape.recognition.confusion import MockRecognizer, MockSettings
from voxshape.world.geodesic import GeodesicDistance, downhill_heading, path_command
from voxshape.world.maps import Map

OPPOSITE = {"good": "bad", "bad": "good", "excellent": "terrible", "terrible": "excellent"}
OPPOSITE.update(goal="terrible", left="right", right="left", forward="back")


@dataclass(frozen=True)
class FeedbackSchedule:
    """The chance the teacher comments on what it saw, by episode: `permanent` until episode
    `permanent_episodes`, then falling linearly to `sporadic` over `fade_episodes`."""

    permanent: float = 1.0
    permanent_episodes: int = 5
    fade_episodes: int = 10
    sporadic: float = 0.2

    def probability(self, episode: int) -> float:
        if episode < self.permanent_episodes:
            return self.permanent
        done = min(1.0, (episode - self.permanent_episodes + 1) / max(1, self.fade_episodes))
        return self.permanent + done * (self.sporadic - self.permanent)


@dataclass(frozen=True)
class Confusion:
    """Relative weights of the kinds of error, when one is made."""

    # The default: the person's slips 10% of words, and what the default speech engine made
    # of the project's held-out vocabulary clips (docs/speech.md): 17% not heard, 1% heard as
    # another phrase; with noise 0.28, words come out wrong in those shares.
    wrong_qualifier: float = 0.10  # the teacher's slip: the opposite judgement
    misheard: float = 0.01  # the recognizer's: another phrase of the vocabulary
    dropped: float = 0.17  # the recognizer's: nothing heard (the word was said all the same)

    def __post_init__(self) -> None:
        weights = (self.wrong_qualifier, self.misheard, self.dropped)
        if min(weights) < 0 or sum(weights) <= 0:
            raise ValueError("confusion weights must be >= 0 and not all 0")

    def draw(self, rng: random.Random) -> str:
        """The kind of an error made: "wrong_qualifier", "misheard" or "dropped"."""
        kinds = ("wrong_qualifier", "misheard", "dropped")
        return rng.choices(kinds, weights=(self.wrong_qualifier, self.misheard, self.dropped))[0]


@dataclass(frozen=True)
class TeacherProfile:
    """How the simulated teacher watches and speaks. The defaults are a person's (`PERSON`):
    at most `rate` words a robot minute, at salient moments; `TIRELESS` is the teacher of
    earlier experiments, who judges every look (docs/experiments.md gives both word rates)."""

    interval: float = 1.0  # seconds of robot time between looks
    small_change: float = 0.1  # metres of geodesic progress (regress) for good (bad) ...
    large_change: float = 0.35  # ... and for excellent (terrible); 0.5 m/s at most
    # A person keeps commenting as long as the budget allows: the budget thins the words.
    schedule: FeedbackSchedule = field(default_factory=lambda: FeedbackSchedule(sporadic=1.0))
    noise: float = 0.0  # probability an utterance comes out wrong
    confusion: Confusion = field(default_factory=Confusion)
    positive_bias: float = 0.0  # share of the scolding left unsaid
    # Seconds without progress (of small_change) after which each look is "bad"; 0: never.
    stuck_after: float = 3.0
    # Seconds before the teacher says the same judgement again (praise, or scolding) while
    # nothing changes: a person says "good" once as the robot sets off on the right way, not
    # every second it keeps going. Bumps and the goal are always said. 0: says every one.
    repeat_after: float = 0.0
    # A person's budget: words a robot minute on average (bumps and the goal included), and
    # at most this many at once; 0 words a minute: no budget.
    words_per_robot_minute: float = 4.0
    words_at_once: float = 2.0
    # Speak at salient moments only, as a person watching does: a bump, the goal, nearing
    # it (within `near_goal` metres of the way), getting going the right way after standing,
    # turning or regressing, turning away after progress, being stuck; not at every look.
    salient: bool = True
    near_goal: float = 1.5
    answers: bool = True  # answers the robot's "which way?" (within the word budget)
    # Steers as well as judges: once the robot has headed more than `off_route` radians away
    # from the way to the goal for `steer_after` seconds, says the command that turns it back
    # ("left", "right"), within the same budget; 0 seconds: never steers.
    steer_after: float = 8.0
    off_route: float = math.radians(45)
    steer_at_bumps: bool = True  # at a bump facing away, the turn back instead of "terrible"
    delay: float = 0.5  # seconds from what is judged being displayed to the onset of speech
    jitter: float = 0.1  # standard deviation of the delay
    speaking: float = 0.4  # seconds a word takes to say
    recognition: float = 0.3  # seconds from the end of speech to the utterance

    def __post_init__(self) -> None:
        for name in ("noise", "positive_bias"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} {getattr(self, name)} is not within [0, 1]")
        if (
            self.interval <= 0
            or min(self.delay, self.jitter, self.stuck_after, self.repeat_after) < 0
        ):
            raise ValueError(
                "interval must be > 0; delay, jitter, stuck_after, repeat_after >= 0 seconds"
            )
        if not 0 < self.small_change <= self.large_change:
            raise ValueError("need 0 < small_change <= large_change (metres)")
        if self.words_per_robot_minute < 0 or self.words_at_once < 1:
            raise ValueError("need words_per_robot_minute >= 0 and words_at_once >= 1")

    def describe(self) -> str:
        """How often it speaks, in a few words."""
        when = "at salient moments" if self.salient else f"judging every {self.interval:g} s"
        rate = self.words_per_robot_minute
        budget = f"at most {rate:g} words a robot minute" if rate else "no budget"
        steers = ", steering when the robot heads away" if self.steer_after else ""
        return f"{budget}, {when}{steers}"


# A person judges and steers: the turn back after 8 s headed away, and at a bump facing away.
PERSON = TeacherProfile()
# The person of earlier figures, who only judges.
JUDGING = TeacherProfile(steer_after=0.0, steer_at_bumps=False)
# Judges every look, with the paper's fading schedule: about 50 words a robot minute.
TIRELESS = TeacherProfile(
    words_per_robot_minute=0.0,
    salient=False,
    schedule=FeedbackSchedule(),
    steer_after=0.0,
    steer_at_bumps=False,
)
PROFILES = {"person": PERSON, "judging": JUDGING, "tireless": TIRELESS}


@dataclass(frozen=True)
class Look:
    """What the teacher sees at one step: its own clock's time and the robot's state."""

    time: float  # when this step is displayed (seconds)
    episode: int
    x: float
    y: float
    collided: bool
    outcome: str  # running, goal, collision, timeout
    heading: float = 0.0  # radians, world frame


@dataclass(frozen=True)
class Speech:
    """One utterance: the words said and heard, when speech starts, and when it is heard."""

    meant: str  # the meaning the teacher had in mind
    said: str  # the text the teacher spoke
    heard: str  # the text recognized ("": nothing was)
    confidence: float
    onset: float  # teacher's clock
    end: float  # of speech
    heard_at: float  # end of speech plus recognition
    error: str | None  # None, "wrong_qualifier", "misheard" or "dropped"


class SimulatedTeacher:
    def __init__(
        self, m: Map, vocabulary: Vocabulary, profile: TeacherProfile, seed: int = 0
    ) -> None:
        self.map = m
        self.profile = profile
        self.vocabulary = vocabulary
        self.distance = GeodesicDistance(m)
        self.rng = random.Random(seed)
        self.recognizer = MockRecognizer(
            vocabulary,
            MockSettings(error_rate=1.0, misheard=1.0, dropped=0.0, inserted=0.0, seed=seed),
        )
        self._last_look: Look | None = None
        self._last_distance = math.inf
        self._bumping = False
        self._progress = (math.inf, 0.0)  # (best distance this episode, when it was reached)
        self._judged = (0.0, -math.inf)  # (sign of the last judgement said, when it was said)
        self._budget = (profile.words_at_once, 0.0)  # (words left, when counted): a token bucket
        self._trend, self._stuck_said, self._neared = 0, False, False  # salient moments
        # When (and how far from the goal) the robot turned away from the way.
        self._off_route_since: tuple[float, float] | None = None

    def phrase(self, meaning: str) -> str:
        """The teacher's words for a meaning: its first English phrase in the vocabulary."""
        return self.vocabulary.meanings[meaning].phrases["en"][0]

    def watch(self, look: Look) -> list[Speech]:
        """What the teacher says about this step (usually nothing)."""
        p = self.profile
        distance = self.distance(look.x, look.y)
        previous = self._last_look
        new_episode = previous is None or previous.episode != look.episode
        bump = look.collided and not self._bumping
        self._bumping = look.collided
        if new_episode:
            self._trend, self._stuck_said, self._neared = 0, False, False
            self._off_route_since = None
            if previous is not None:  # the pause between episodes is no robot time
                self._refill(previous.time)
                self._budget = (self._budget[0], look.time)
        if new_episode or distance <= self._progress[0] - p.small_change:
            self._progress = (distance, look.time)
        looks = not new_episode and look.time - previous.time >= p.interval - 1e-9
        meaning = None
        if look.outcome == "goal":
            meaning = "goal"
        elif bump:
            # A bump: the way round it, if the person steers and the robot faces away.
            meaning = (self._way_back(look) if p.steer_at_bumps else None) or "terrible"
        elif looks:
            meaning = self._steer(look, distance)
        if meaning is None and looks:  # no command: a judgement, if anything
            stuck = bool(p.stuck_after) and look.time - self._progress[1] >= p.stuck_after
            progress = self._last_distance - distance
            meaning = (self._salient if p.salient else self._every_look)(progress, distance, stuck)
        if new_episode or meaning is not None or looks:
            self._last_look, self._last_distance = look, distance
        if meaning is None or self._repeats(meaning, look.time, bump or meaning == "goal"):
            return []
        if not self._speaks(look.episode, meaning) or not self._afford(look.time):
            return []
        self._judged = (self._valence(meaning), look.time)
        return [self._say(meaning, look.time + self._reaction())]

    def _steer(self, look: Look, distance: float) -> str | None:
        """The command back to the way, once the robot has headed away from it for
        `steer_after` seconds, moving away from the goal (not turning on the spot) (None: no
        command now)."""
        p = self.profile
        if not p.steer_after:
            return None
        command = self._way_back(look)
        if command is None:
            self._off_route_since = None
            return None
        if self._off_route_since is None:
            self._off_route_since = (look.time, distance)
        since, then = self._off_route_since
        if look.time - since < p.steer_after or distance < then + p.small_change:
            return None
        self._off_route_since = (look.time, distance)  # said: the next after as long again
        return command

    def _way_back(self, look: Look) -> str | None:
        """The turn towards the way to the goal when the robot heads more than `off_route`
        away from it (None: it heads along the way)."""
        way = downhill_heading(self.map, look.x, look.y)
        if (
            way is None
            or abs(math.remainder(way - look.heading, math.tau)) <= self.profile.off_route
        ):
            return None
        return path_command(self.map, look.x, look.y, look.heading)

    def _every_look(self, progress: float, distance: float, stuck: bool) -> str | None:
        """The tireless teacher: its judgement of every look's progress, "bad" when stuck."""
        meaning = self.judge(progress)
        return "bad" if meaning is None and stuck else meaning

    def _salient(self, progress: float, distance: float, stuck: bool) -> str | None:
        """A person's teacher: a word only where the robot's course changes."""
        sign = 0 if abs(progress) < self.profile.small_change else (1 if progress > 0 else -1)
        previous, self._trend = self._trend, sign or self._trend
        if sign > 0:
            self._stuck_said = False
            if not self._neared and distance <= self.profile.near_goal:
                self._neared = True
                return "excellent"  # nearly there
            return "good" if previous <= 0 else None  # set off the right way
        if sign < 0:
            return "bad" if previous > 0 else None  # turned away after progress
        if stuck and not self._stuck_said:
            self._stuck_said = True
            self._trend = 0
            return "bad"  # standing, turning on the spot or pinned
        return None

    def _afford(self, now: float) -> bool:
        """Whether the word budget has a word left (and spends it)."""
        if not self.profile.words_per_robot_minute:
            return True
        tokens = self._refill(now)
        if tokens < 1:
            return False
        self._budget = (tokens - 1, now)
        return True

    def _refill(self, now: float) -> float:
        """The budget refilled for the robot time until `now`: words left."""
        p = self.profile
        tokens, since = self._budget
        refill = max(0.0, now - since) * p.words_per_robot_minute / 60
        tokens = min(p.words_at_once, tokens + refill)
        self._budget = (tokens, now)
        return tokens

    def judge(self, progress: float) -> str | None:
        """The qualifier for `progress` metres towards the goal (negative: away from it)."""
        p = self.profile
        size = abs(progress)
        if size < p.small_change:
            return None
        if progress > 0:
            return "excellent" if size >= p.large_change else "good"
        return "terrible" if size >= p.large_change else "bad"

    def _valence(self, meaning: str) -> float:
        return math.copysign(1.0, self.vocabulary.meanings[meaning].reward or 0.0)

    def _repeats(self, meaning: str, now: float, event: bool) -> bool:
        """The judgement is the one said less than `repeat_after` seconds ago."""
        said, when = self._judged
        return (
            not event and self._valence(meaning) == said and now - when < self.profile.repeat_after
        )

    def _speaks(self, episode: int, meaning: str) -> bool:
        p = self.profile
        if self.rng.random() >= p.schedule.probability(episode):
            return False
        negative = self._valence(meaning) < 0
        return not (negative and self.rng.random() < p.positive_bias)

    def _reaction(self) -> float:
        """Seconds from seeing to starting to speak."""
        return max(0.0, self.rng.gauss(self.profile.delay, self.profile.jitter))

    def _say(self, meaning: str, onset: float) -> Speech:
        p = self.profile
        heard_at = onset + p.speaking + p.recognition
        said, heard, confidence, error = self.phrase(meaning), None, 0.95, None
        if self.rng.random() < p.noise:
            error = p.confusion.draw(self.rng)
            if error == "wrong_qualifier":
                said = self.phrase(OPPOSITE[meaning])
            elif error == "dropped":
                heard = ""
            else:
                (wrong,) = self.recognizer.hear(said, "en")
                heard, confidence = wrong.text, wrong.confidence
        end = onset + p.speaking
        heard = said if heard is None else heard
        return Speech(meaning, said, heard, confidence, onset, end, heard_at, error)

    def command(self, x: float, y: float, theta: float) -> str:
        """The command the teacher dictates at this pose (initial traces)."""
        return path_command(self.map, x, y, theta)

    def answer(self, look: Look) -> Speech | None:
        """The answer to "which way?" asked at this look: the command along the shortest
        path, after its reaction delay, within the word budget (None: it stays silent)."""
        if not self.profile.answers or not self._afford(look.time):
            return None
        meaning = self.command(look.x, look.y, look.heading)
        return self._say(meaning, look.time + self._reaction())
