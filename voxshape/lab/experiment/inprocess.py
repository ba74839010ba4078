"""One training run of an experiment, in one process: the simulator, learner, arbiter and
simulated teacher cores stepped together, no bus. Fast and deterministic for a seed.

Time: the robot steps every control period (10 Hz) on a clock that is also the teacher's and
the arbiter's (as in a lockstep session with synced clocks); between episodes the clock runs
on for `PAUSE` seconds, so words about an episode's end still reach it. At each step:

    the arbiter sees the observation (its step timeline, bumps and goals for delay learning)
    the teacher watches the step and may start speaking (onset = display + its delay); what
        it said is heard `speaking + recognition` seconds after the onset
    utterances heard by now go to the arbiter (Arbiter.on_utterance at that time): the real
        delay correction picks the credited steps; its CreditedFeedback goes to the agent
        (Agent.take, as in the learner service: learner/agent.py)
    the learner learns from the step and decides the next action (Agent.step), and may ask

Interventions are the utterances the arbiter understood (its own count), per episode.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np

from voxshape.lab.experiment.bouts import BumpBouts
from voxshape.lab.experiment.dictation import Dictation, dictate
from voxshape.protocol import CreditedFeedback, TeacherNotice, Utterance
from voxshape.protocol.vocabulary import load_vocabulary
from voxshape.runtime.settings import replaced
from voxshape.services.arbiter.arbiter import Arbiter
from voxshape.services.arbiter.config import ArbiterConfig, DelayLearning
from voxshape.services.learner.agent import Agent
from voxshape.services.learner.asking import Asker, Question
from voxshape.services.learner.config import LearnerConfig, with_settings
from voxshape.services.learner.convergence import Convergence, EpisodeResult, convergence_on
from voxshape.services.learner.potential import Place
from voxshape.services.learner.sarsa import Learner
from voxshape.services.sim.stepper import observation
from voxshape.services.sim.task import Reading, SimConfig, Simulation
from voxshape.services.simteacher.dictating import DictationProfile
from voxshape.services.simteacher.teacher import Look, SimulatedTeacher, Speech, TeacherProfile
from voxshape.world.geodesic import way_ahead
from voxshape.world.maps import Map, load_map

START = 1_700_000_000.0  # the session clock at the first step (seconds)
PAUSE = 3.0  # seconds between episodes (the robot is put back at the start)
ROBOT, TEACHER = "r1", "teacher"


@dataclass(frozen=True)
class Setting:
    """What the robot gets from its teacher."""

    feedback: bool  # the teacher judges while the robot learns
    traces: int  # episodes the teacher dictates before learning (initial traces)
    noise: float  # probability an utterance comes out wrong
    ask: bool = False  # the robot asks "which way?" (learner/asking.py)


# The paper's four settings (Section 4), its ~20% of errors made ours: 28% of words come out
# wrong, the person's slips (10%) and the speech engine's drops and mishearings (18%), as
# Confusion's defaults measure them (voxshape/services/simteacher/teacher.py).
NOISE = 0.28
SETTINGS: dict[str, Setting] = {
    "rl": Setting(feedback=False, traces=0, noise=0.0),
    "rl+f": Setting(feedback=True, traces=0, noise=NOISE),
    "rl+f-perfect": Setting(feedback=True, traces=0, noise=0.0),
    "rl+t": Setting(feedback=False, traces=1, noise=NOISE),  # traces alone, no words after
    "rl+t+f": Setting(feedback=True, traces=1, noise=NOISE),
    "rl+t+f-perfect": Setting(feedback=True, traces=1, noise=0.0),
    "rl+f+ask": Setting(feedback=True, traces=0, noise=NOISE, ask=True),
    "rl+t+f+ask": Setting(feedback=True, traces=1, noise=NOISE, ask=True),
}
PAPER_SETTINGS = ("rl", "rl+f", "rl+t", "rl+t+f", "rl+t+f-perfect")  # the paper's, and T alone


@dataclass(frozen=True)
class RunSpec:
    task: str
    setting: str
    seed: int
    max_episodes: int = 150
    noise: float | None = None  # None: the setting's
    delay: float | None = None  # the teacher's mean reaction delay; None: the profile's
    delay_learning: bool = True  # the arbiter learns the teacher's delay (else TAMER's window)
    traces: int | None = None  # episodes dictated before learning; None: the setting's
    profile: TeacherProfile = field(default_factory=TeacherProfile)
    learner: tuple[str, ...] = ()  # KEY=VALUE changes to LearnerConfig (`--set`)
    teacher: tuple[str, ...] = ()  # KEY=VALUE changes to the profile (`--teacher`)


@dataclass
class RunResult:
    task: str
    setting: str
    seed: int
    converged: bool  # False: censored at max_episodes, its time so far counted
    episodes: int
    learning_time_s: float
    interventions: int  # words said until convergence (or the end), heard or not
    trace_steps: int  # steps of the dictated traces
    durations_s: list[float]  # robot seconds of every episode run
    delay_learned: bool  # the arbiter learnt the teacher's reaction delay
    delay_window_s: tuple[float, float]  # the arbiter's window at the end (seconds)
    counters: dict[str, int]
    dictation_s: float = 0.0  # robot seconds spent dictating the traces, before learning
    dictation_words: int = 0  # the commands the person said to dictate them
    outcomes: list[str] = field(default_factory=list)  # of every episode run
    bump_bout_s: float = 0.0  # robot seconds in bump bouts of 10 s or more until convergence
    bump_bouts_s: list[float] = field(default_factory=list)  # ... in each episode run
    states: int = 0  # the learner's states at the end
    timeout_s: float = 0.0  # of the map's episodes (0: not recorded)
    # Of the greedy decisions until convergence, the share the person's input changed against
    # what the robot would have done without it; of those, the share that led along the true
    # shortest way (nearer the goal by the map's geodesic distance) rather than against it.
    changed_by_person: float = 0.0
    changed_toward_way: float | None = None
    spec: dict = field(default_factory=dict)  # how it was run: the RunSpec, teacher included

    @property
    def robot_time_s(self) -> float:
        """Robot seconds the person's teaching took: dictating the traces, then learning."""
        return self.learning_time_s + self.dictation_s

    @property
    def words(self) -> int:
        """Every word the person said: dictating, then understood while the robot learnt."""
        return self.interventions + self.dictation_words

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict) -> RunResult:
        """A run as runs.jsonl or results.json keep it; fields of earlier builds that are
        gone are left out (ValueError: not a run)."""
        known = {f.name for f in fields(cls)}
        try:
            return cls(**{k: v for k, v in data.items() if k in known})
        except TypeError as e:
            raise ValueError(f"not a run: {e}") from None


def run(
    spec: RunSpec,
    reference: bool = False,
    on_episode: Callable[[EpisodeResult, Learner], None] | None = None,
) -> RunResult:
    """Trains one robot on one task in one setting until convergence or max_episodes. The
    simulator senses only as far as the learner reads (SimConfig.sensor_reach), on its fast
    path; `reference` runs the reference path with full scans instead: the same results,
    slower (benchmarks/experiment.py compares them). `on_episode` sees each episode."""
    m = load_map(spec.task)
    learner_config = with_settings(list(spec.learner))
    session = _Session(spec, m, learner_config, reference)
    progress = convergence_on(m, learner_config)
    dictation = initial_traces(spec, m)
    book = dictation.book if dictation else None
    try:
        for episode in range(spec.max_episodes):
            if book and episode == 0:
                book.show(session.learner)
            result = session.episode()
            if on_episode is not None:
                on_episode(result, session.learner)
            if progress.add(result):
                break
    finally:
        session.sim.close()
    return session.result(spec, progress, dictation)


class _Session:
    """The cores of one run, stepped together on one clock (the module's docstring)."""

    def __init__(self, spec: RunSpec, m: Map, config: LearnerConfig, reference: bool) -> None:
        setting = SETTINGS[spec.setting]
        vocabulary = load_vocabulary()
        profile = replaced(spec.profile, list(spec.teacher), "--teacher")
        profile = replace(
            profile,
            noise=setting.noise if spec.noise is None else spec.noise,
            delay=profile.delay if spec.delay is None else spec.delay,
        )
        self.learner = Learner(config, seed=spec.seed, task=m)
        self.toward = [0, 0]  # changed decisions that led along the way, and all of them
        self.learner.on_changed = self._judge_change
        self.teacher = (
            SimulatedTeacher(m, vocabulary, profile, seed=spec.seed) if setting.feedback else None
        )
        self.arbiter = Arbiter(
            ArbiterConfig(learning=replace(DelayLearning(), enabled=spec.delay_learning)),
            vocabulary,
        )
        self.asker = Asker(self.learner, m.timeout) if setting.ask else None
        self.agent = Agent(self.learner, self.asker)
        self.heard: list[tuple[float, int, Utterance]] = []  # (heard at, order, utterance)
        reach = None if reference else self.learner.reach
        sim_config = SimConfig(sensor_reach=reach, fast=not reference)
        self.sim = Simulation(m, (ROBOT,), sim_config, seed=spec.seed)
        self.now, self.order = START, 0
        self.durations: list[float] = []
        self.outcomes: list[str] = []
        self.bouts = BumpBouts(self.sim.config.control_period)
        self.bump_bouts: list[float] = []
        self.answers = 0  # the teacher's answers to questions
        self.unheard = 0  # words said that the speech engine did not hear, this episode

    def episode(self) -> EpisodeResult:
        """One episode, to its end; the words about it are delivered in the pause after."""
        sim, period = self.sim, self.sim.config.control_period
        interventions = 0
        reading = sim.reset(ROBOT)
        for _ in range(sim.max_episode_steps + 1):
            self.arbiter.on_observation(observation(reading, self.now, scans=False), self.now)
            if self.teacher is not None:
                for speech in self.teacher.watch(look(reading, self.now)):
                    self._hear(speech)
            interventions += self._deliver()
            decision, question = self.agent.step(reading, reading.episode)
            if question is not None:
                self._ask(reading, question)
            if decision is None:
                break
            reading = sim.step({ROBOT: (decision.v, decision.omega)})[ROBOT]
            self.bouts.step(reading.episode_step * period, reading.collided)
            self.now += period
        self.bump_bouts.append(self.bouts.end())
        self.now += PAUSE
        interventions += self._deliver() + self.unheard
        self.unheard = 0
        seconds = reading.episode_step * period
        self.durations.append(seconds)
        self.outcomes.append(reading.outcome)
        return EpisodeResult(reading.outcome, reading.episode_step, seconds, interventions)

    def _judge_change(self, here: Place, chosen: Place, unchanged: Place) -> None:
        """A decision the person's input changed: does where it leads point along the map's
        true shortest way (towards the point a metre down it) better than where the robot
        would have gone without it?"""
        aim = way_ahead(self.sim.map, *here, 1.0)
        if aim is None:
            return
        self.toward[1] += 1
        self.toward[0] += alignment(here, chosen, aim) > alignment(here, unchanged, aim)

    def _ask(self, reading: Reading, question: Question) -> None:
        """The robot asks which way (the arbiter hears it); the teacher may answer."""
        self.arbiter.on_help(question.request(ROBOT, reading.pose.x, reading.pose.y), self.now)
        speech = self.teacher.answer(look(reading, self.now)) if self.teacher else None
        if speech is not None:
            self._hear(speech)
            self.answers += 1

    def _hear(self, speech: Speech) -> None:
        if not speech.heard:  # said, and not heard: a word all the same
            self.unheard += 1
            return
        heapq.heappush(self.heard, (speech.heard_at, self.order, utterance(speech)))
        self.order += 1

    def _deliver(self) -> int:
        """The utterances heard by now to the arbiter, its feedback to the learner; returns
        how many the arbiter understood (interventions)."""
        understood = 0
        while self.heard and self.heard[0][0] <= self.now:
            at, _, said = heapq.heappop(self.heard)
            for message in self.arbiter.on_utterance(said, at):
                if isinstance(message, CreditedFeedback):
                    self.agent.take(message)
                elif isinstance(message, TeacherNotice) and message.kind == "understood":
                    understood += 1
        return understood

    def result(
        self, spec: RunSpec, progress: Convergence, dictation: Dictation | None
    ) -> RunResult:
        learner, arbiter = self.learner, self.arbiter
        window = arbiter.delay_window(TEACHER)
        counters = {f"arbiter.{k}": v for k, v in arbiter.counters.items()}
        counters.update({f"learner.{k}": v for k, v in learner.counters.items()})
        if self.asker is not None:
            counters["learner.questions"] = sum(self.asker.reasons.values())
            counters.update({f"learner.asked.{k}": v for k, v in self.asker.reasons.items()})
            counters["teacher.answers"] = self.answers
        greedy, changed = learner.counters["decisions_judged"], self.toward[1]
        return RunResult(
            task=spec.task,
            setting=spec.setting,
            seed=spec.seed,
            converged=progress.converged,
            episodes=progress.n_episodes,
            learning_time_s=round(progress.learning_time, 1),
            interventions=progress.interventions,
            trace_steps=sum(len(e) for e in dictation.book.episodes) if dictation else 0,
            dictation_s=round(dictation.seconds, 1) if dictation else 0.0,
            dictation_words=dictation.words if dictation else 0,
            durations_s=self.durations,
            delay_learned=arbiter.delay_learned(TEACHER),
            delay_window_s=(round(window.lo, 3), round(window.hi, 3)),
            counters=counters,
            outcomes=self.outcomes,
            bump_bout_s=round(sum(self.bump_bouts[: progress.n_episodes]), 1),
            bump_bouts_s=self.bump_bouts,
            states=len(learner.states),
            timeout_s=self.sim.map.timeout,
            changed_by_person=round(changed / greedy, 4) if greedy else 0.0,
            changed_toward_way=round(self.toward[0] / changed, 3) if changed else None,
            spec=asdict(spec),
        )


def initial_traces(spec: RunSpec, m: Map | None = None) -> Dictation | None:
    """The episodes the person dictates before learning in the run's setting, with the
    actions of the run's learner, heard with the setting's errors (None: none)."""
    setting = SETTINGS[spec.setting]
    traces = setting.traces if spec.traces is None else spec.traces
    if not traces:
        return None
    config = with_settings(list(spec.learner))
    noise = setting.noise if spec.noise is None else spec.noise
    profile = DictationProfile(noise=noise, confusion=spec.profile.confusion)
    m = m or load_map(spec.task)
    return dictate(m, traces, seed=10_000 + spec.seed, config=config, profile=profile)


def alignment(here: Place, there: Place, aim: Place) -> float:
    """The cosine between the move from here to there and the direction from here to aim."""
    move, way = np.subtract(there, here), np.subtract(aim, here)
    norms = float(np.hypot(*move) * np.hypot(*way))
    return float(move @ way) / norms if norms > 1e-9 else -1.0


def look(reading: Reading, now: float) -> Look:
    pose = reading.pose
    return Look(now, reading.episode, pose.x, pose.y, reading.collided, reading.outcome, pose.theta)


def utterance(speech: Speech) -> Utterance:
    return Utterance(
        teacher=TEACHER,
        robot=ROBOT,
        text=speech.heard,
        confidence=speech.confidence,
        onset=speech.onset,
        end=speech.end,
        recognized_at=speech.heard_at,
        engine="mock",
        language="en",
        alternatives=(),
    )
