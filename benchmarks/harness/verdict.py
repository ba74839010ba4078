"""The verdict of a chaos session: from the event log, the learners' checkpoints, the probe and
the services' counters, did every word the arbiter understood reach its learner exactly once,
did every learner converge, does the event log read to its end, does a replay show what the
live recording shows.
"""

from __future__ import annotations

import json
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.harness.replay import compare_replay
from benchmarks.harness.session import Session
from benchmarks.probe import Probe
from voxshape.protocol import CreditedFeedback, Said, TeacherNotice, Utterance
from voxshape.services.arbiter.replies import feedback_id
from voxshape.services.speech.transcriber import heard_id


@dataclass
class Verdict:
    said: dict[str, int]  # robot -> words its teacher said
    understood: dict[str, int]
    reached: dict[str, int]
    lost: dict[str, list[str]]  # robot -> understood words no taken feedback holds
    duplicated: dict[str, list[str]]  # robot -> words in two or more taken feedback
    episodes: dict[str, int]
    converged: dict[str, str]  # robot -> "after N episodes" or "no"
    log_records: int
    log_tail: str | None
    replay_equal: bool
    replay_note: str
    missed: dict[str, int]  # counters `missed.*` summed over the services' last counters
    problems: list[str]

    @property
    def ok(self) -> bool:
        return not self.problems


def checkpoint_meta(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as data:
        return json.loads(str(data["meta"]))


@dataclass
class Words:
    """What the event log and the probe saw of the teachers' words, each message once."""

    notices: dict[str, TeacherNotice] = field(default_factory=dict)
    feedback: dict[str, CreditedFeedback] = field(default_factory=dict)
    utterances: dict[str, Utterance] = field(default_factory=dict)
    said: dict[str, set[str]] = field(default_factory=lambda: defaultdict(set))  # robot -> ids
    heard_in: dict[str, tuple] = field(default_factory=dict)  # utterance id -> its said word

    def add(self, m: object) -> None:
        if isinstance(m, TeacherNotice):
            self.notices.setdefault(m.id, m)
        elif isinstance(m, CreditedFeedback):
            self.feedback.setdefault(m.id, m)
        elif isinstance(m, Utterance):
            self.utterances.setdefault(m.id, m)
        elif isinstance(m, Said):
            self.said[m.robot].add(m.id)
            self.heard_in.update({heard_id(m.id, i): (m.id, i) for i in (0, 1)})

    def word(self, utterance_id: str) -> tuple:
        """A word is what a teacher said once. The mock engine's utterances derive their ids
        from the said message (heard_id): a restarted speech service hears it again with those
        ids. Other utterances share teacher, onset and end (an engine that hears the audio
        again makes another utterance of it); distinct said messages may share those (two
        words whose steps fell in one gap of the teacher's display)."""
        if utterance_id in self.heard_in:
            return self.heard_in[utterance_id]
        u = self.utterances.get(utterance_id)
        return (utterance_id,) if u is None else (u.teacher, u.onset, u.end)

    def understood(self, robot: str) -> set[str]:
        """The utterance ids the arbiter understood for `robot`."""
        return {
            n.utterance
            for n in self.notices.values()
            if n.kind == "understood" and n.robot == robot
        }


@dataclass(frozen=True)
class Reached:
    """One robot's understood words, and which of them its learner took once, never, twice."""

    understood: int
    reached: int
    lost: list[str]
    duplicated: list[str]


def words_seen(records: list, probe: Probe) -> Words:
    """The words of the event log's records, and those only the probe saw."""
    from voxshape.services.logger.decoding import Known, decode_record

    words = Words()
    for record in records:
        decoded = decode_record(record)
        if isinstance(decoded, Known):
            words.add(decoded.message)
    with probe.lock:
        seen = probe.seen
        for _, m in [*seen.notices.values(), *seen.feedback.values(), *seen.utterances.values()]:
            words.add(m)
    return words


def reached(words: Words, robot: str, taken: set[str]) -> Reached:
    """Which of `robot`'s understood words the feedback its learner took (`taken`) holds."""
    by_word: dict[tuple, set[str]] = defaultdict(set)  # word -> taken feedback ids
    for fb in words.feedback.values():
        if fb.robot == robot and fb.id in taken:
            for u in fb.sources:
                by_word[words.word(u)].add(fb.id)
    understood = words.understood(robot)
    for u in understood:  # feedback of one word that nobody saw published
        for kind in ("reward", "command"):
            if (fid := feedback_id(robot, kind, (u,))) in taken:
                by_word[words.word(u)].add(fid)
    heard = {words.word(u) for u in understood}
    return Reached(
        understood=len(heard),
        reached=sum(1 for w in heard if by_word.get(w)),
        lost=sorted(str(w) for w in heard if not by_word.get(w)),
        duplicated=sorted(str(w) for w, ids in by_word.items() if len(ids) > 1),
    )


def convergence(run: object, robots: tuple[str, ...]) -> tuple[dict[str, int], dict[str, str]]:
    """Each robot's episodes, and whether (after how many) it converged, as the report
    counts them."""
    from voxshape.lab.report import load_run

    counts = load_run(run).counts()
    episodes, converged = {}, {}
    for robot in robots:
        c = counts.get(robot)
        episodes[robot] = 0 if c is None else c.ended
        done = c is not None and c.convergence.converged
        converged[robot] = f"after {c.convergence.n_episodes}" if done else "no"
    return episodes, converged


def verify(
    session: Session,
    probe: Probe,
    counters: dict[str, dict],
    teacher_counters: dict[str, dict],
    replay: bool = True,
    convergence_needed: bool = True,
) -> Verdict:
    """What held, from the run's files, the probe and the counters."""
    from voxshape.services.logger.eventlog import read_events
    from voxshape.services.logger.run import RunDir

    run = RunDir(session.run_dir)
    log = read_events(run.events)
    words = words_seen(log.records, probe)
    by_robot = {}
    for robot in session.robots:
        meta = checkpoint_meta(session.run_dir / f"learner-{robot}.npz")
        by_robot[robot] = reached(words, robot, set(meta["feedback_taken"]))
    said = {
        r: int(teacher_counters.get(r, {}).get("sent.said", 0)) or len(words.said[r])
        for r in session.robots
    }
    episodes, converged = convergence(run, session.robots)
    missed = Counter()
    for values in counters.values():
        missed.update({k: int(v) for k, v in values.items() if k.startswith("missed.")})
    replay_equal, note = compare_replay(session) if replay else (True, "not compared")
    verdict = Verdict(
        said=said,
        understood={r: x.understood for r, x in by_robot.items()},
        reached={r: x.reached for r, x in by_robot.items()},
        lost={r: x.lost for r, x in by_robot.items()},
        duplicated={r: x.duplicated for r, x in by_robot.items()},
        episodes=episodes,
        converged=converged,
        log_records=len(log.records),
        log_tail=log.describe_tail(),
        replay_equal=replay_equal,
        replay_note=note,
        missed=dict(missed),
        problems=[],
    )
    verdict.problems += problems(verdict, session.robots, convergence_needed)
    return verdict


def problems(v: Verdict, robots: tuple[str, ...], convergence_needed: bool) -> list[str]:
    """What did not hold: words lost or taken twice, a learner that did not converge (when
    required), a replay unlike the live recording."""
    found = []
    for robot in robots:
        if v.lost[robot]:
            found.append(f"{robot}: {len(v.lost[robot])} understood words never taken")
        if v.duplicated[robot]:
            found.append(f"{robot}: {len(v.duplicated[robot])} words taken twice")
        if convergence_needed and v.converged[robot] == "no":
            found.append(f"{robot}: did not converge in {v.episodes[robot]} episodes")
    if not v.replay_equal:
        found.append(f"replay differs from the live recording: {v.replay_note}")
    return found


def verdict_table(v: Verdict, robots: tuple[str, ...]) -> str:
    head = "| robot | said | understood | reached the learner | lost | duplicated | episodes |"
    lines = [head + " converged |", "|---|---|---|---|---|---|---|---|"]
    for r in robots:
        lines.append(
            f"| {r} | {v.said[r]} | {v.understood[r]} | {v.reached[r]} | {len(v.lost[r])} | "
            f"{len(v.duplicated[r])} | {v.episodes[r]} | {v.converged[r]} |"
        )
    return "\n".join(lines)
