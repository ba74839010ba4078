"""A scripted robot and teacher for the arbiter's core, without the bus: how often the credit
lands on the step the teacher reacted to, for a chosen reaction delay and clock skew.

The robot steps every `period` seconds (with a little timing jitter) and now and then bumps
into something. The teacher's clock is `skew` seconds off; they sync it with the arbiter at
the start (the real exchange: the core's ClockReply and the client's estimate, with random
network delays), react `delay` seconds after the result of an action is displayed (the
observation after it): "bad" after each bump, and a judgement now and then on another step,
positive or negative. Speaking, recognition and transport take a while more before the
utterance arrives. Each judgement's truth is the step whose action it is about.
"""

from __future__ import annotations

import heapq
import random
import statistics
from dataclasses import dataclass, field, replace

from voxshape.protocol import ClockProbe, ClockReply, CreditedFeedback, Observation, Utterance
from voxshape.protocol.vocabulary import load_vocabulary
from voxshape.runtime.clock import ClockEstimate, estimate_from
from voxshape.services.arbiter.arbiter import Arbiter
from voxshape.services.arbiter.config import ArbiterConfig, DelayLearning

START = 1_700_000_000.0  # true time of the first step


def scripted_observation(
    robot: str,
    step: int,
    wall_time: float,
    *,
    episode: int = 0,
    episode_step: int | None = None,
    collided: bool = False,
    outcome: str = "running",
) -> Observation:
    """A plausible observation with the timing fields that matter to the arbiter."""
    return Observation(
        robot=robot,
        episode=episode,
        step=step,
        episode_step=step if episode_step is None else episode_step,
        sim_time=step * 0.1,
        wall_time=wall_time,
        x=1.0,
        y=1.0,
        theta=0.0,
        v=0.3,
        omega=0.0,
        laser=(4.0,) * 180,
        sonar=(1.5,) * 8,
        reward=-1.0,
        goal_distance=3.0,
        goal_bearing=0.1,
        outcome=outcome,  # type: ignore[arg-type]
        collided=collided,
    )


def scripted_utterance(
    teacher: str, robot: str, text: str, onset: float, *, confidence: float = 0.95
) -> Utterance:
    return Utterance(
        teacher=teacher,
        robot=robot,
        text=text,
        confidence=confidence,
        onset=onset,
        end=onset + 0.4,
        recognized_at=onset + 0.7,
        engine="mock",
        language="en",
        alternatives=(),
    )


@dataclass(frozen=True)
class ScriptedTeacher:
    name: str = "ana"
    delay: float = 1.0  # seconds from an action's result on screen to the onset of speech
    skew: float = 0.0  # this teacher's clock minus the true time
    jitter: float = 0.0  # standard deviation of the delay
    sync: bool = True  # syncs its clock with the arbiter at the start


@dataclass
class Rehearsal:
    """Per judgement: (truth step, credited weighted-mean step, heaviest credited step)."""

    judged: list[tuple[int, float, int]] = field(default_factory=list)
    learned_after: int | None = None  # judgements credited before the delay was learnt
    clock_error: float | None = None  # estimated offset minus the true one, seconds

    def within_one_step(self, after_learning: bool = True) -> float:
        rows = self.judged[self.learned_after or 0 :] if after_learning else self.judged
        if not rows:
            return 0.0
        return sum(abs(centre - truth) <= 1.0 for truth, centre, _ in rows) / len(rows)

    def median_error(self, after_learning: bool = True) -> float:
        rows = self.judged[self.learned_after or 0 :] if after_learning else self.judged
        return statistics.median(centre - truth for truth, centre, _ in rows) if rows else 0.0


def sync_in_process(
    arbiter: Arbiter, teacher: ScriptedTeacher, true_now: float, rng: random.Random, n: int = 8
) -> tuple[ClockEstimate, float]:
    """The clock exchange of `voxshape/runtime/clock.py`, with random one-way delays of
    0.2-3 ms; returns (the best estimate, the true time after it)."""
    best: ClockEstimate | None = None
    t = true_now
    for _ in range(n + 1):
        probe = ClockProbe(
            teacher=teacher.name,
            t0=t + teacher.skew,
            offset=best.offset if best else None,
            rtt=best.rtt if best else None,
        )
        arrived = t + rng.uniform(2e-4, 3e-3)
        (reply,) = arbiter.on_clock_probe(probe, arrived, arrived + 5e-5)
        assert isinstance(reply, ClockReply)
        t = arrived + 5e-5 + rng.uniform(2e-4, 3e-3)
        estimate = estimate_from(reply, t + teacher.skew)
        if best is None or estimate.rtt < best.rtt:
            best = estimate
    assert best is not None
    return best, t


def rehearse(
    teacher: ScriptedTeacher,
    *,
    steps: int = 3000,
    period: float = 0.1,
    bump_every: tuple[int, int] = (30, 80),
    judge_every: tuple[int, int] = (10, 25),
    learn: bool = True,
    seed: int = 0,
    config: ArbiterConfig | None = None,
) -> Rehearsal:
    """Runs the scripted session through a fresh arbiter core; every event at its true time."""
    rng = random.Random(seed)
    config = config or ArbiterConfig(
        utterances_per_s=50.0,
        utterances_at_once=50.0,
        learning=replace(DelayLearning(), enabled=learn),
    )
    arbiter = Arbiter(config, load_vocabulary())
    result = Rehearsal()
    robot = "r1"
    if teacher.sync:
        estimate, _ = sync_in_process(arbiter, teacher, START - 1.0, rng)
        result.clock_error = estimate.offset - (-teacher.skew)
    shown = [START + (k + rng.uniform(-0.03, 0.03)) * period for k in range(steps + 1)]
    bumps = _bumps(steps, bump_every, rng)
    reactions = _reactions(steps, bumps, judge_every, rng)
    # Events on the true clock: (time, order, kind, payload); order keeps ties stable.
    events: list[tuple[float, int, str, object]] = []
    for k in range(steps + 1):
        events.append((shown[k] + 3e-4, len(events), "obs", k))
    truth: dict[str, int] = {}
    for step, text in reactions:
        onset = shown[step + 1] + max(0.0, rng.gauss(teacher.delay, teacher.jitter))
        said = scripted_utterance(teacher.name, robot, text, onset + teacher.skew)
        truth[said.id] = step
        arrival = onset + 0.4 + rng.uniform(0.1, 0.6) + rng.uniform(2e-4, 3e-3)
        events.append((arrival, len(events), "utterance", said))
    heapq.heapify(events)
    while events:
        t, _, kind, payload = heapq.heappop(events)
        if kind == "obs":
            k = int(payload)  # type: ignore[call-overload]
            arbiter.on_observation(scripted_observation(robot, k, shown[k], collided=k in bumps), t)
            continue
        assert isinstance(payload, Utterance)
        _judge(arbiter, teacher.name, payload, t, truth[payload.id], result)
    return result


def _bumps(steps: int, every: tuple[int, int], rng: random.Random) -> set[int]:
    """The steps the robot bumps into something at, `every` (min, max) steps apart."""
    bumps: set[int] = set()
    k = rng.randint(*every)
    while k < steps:
        bumps.add(k)
        k += rng.randint(*every)
    return bumps


def _reactions(
    steps: int, bumps: set[int], every: tuple[int, int], rng: random.Random
) -> list[tuple[int, str]]:
    """(step, text) the teacher says about: "bad" for the step before each bump, and a random
    judgement every (min, max) steps on a step whose result is not a bump."""
    reactions: list[tuple[int, str]] = [(k - 1, "bad") for k in sorted(bumps)]
    j = rng.randint(*every)
    while j < steps - 1:
        if j + 1 not in bumps:
            reactions.append((j, rng.choice(("good", "bad", "excellent", "terrible"))))
        j += rng.randint(*every)
    return reactions


def _judge(
    arbiter: Arbiter, teacher: str, said: Utterance, t: float, truth: int, result: Rehearsal
) -> None:
    """Hands `said` to the arbiter at `t` and records where its reward was credited, against
    the step it was about (and when the teacher's delay was first learnt)."""
    learned = arbiter.delay_learned(teacher)
    for message in arbiter.on_utterance(said, t):
        if isinstance(message, CreditedFeedback) and message.kind == "reward":
            steps_weights = [(c.step, c.weight) for c in message.credits]
            centre = sum(s * w for s, w in steps_weights)
            heaviest = max(steps_weights, key=lambda sw: sw[1])[0]
            result.judged.append((truth, centre, heaviest))
            if learned and result.learned_after is None:
                result.learned_after = len(result.judged) - 1
