"""The arbiter's core: the only place where words become numbers. No bus here: messages and
the arbiter's clock in, messages out (the node publishes each on its key).

An utterance goes through, in order (each refusal is counted as `rejected.<reason>`; the
teacher gets a TeacherNotice for those marked *):
  teacher_mismatch   the utterance names another teacher than the key it came on
  duplicate          a message id seen before (the first copy was answered)
  too_many_teachers  more than `max_teachers` teachers
  rate_limited *     the teacher's token bucket is empty (one notice per second at most;
                     a robot-time teacher's rate is per robot second)
  unknown_robot *    no observation of that robot within the remembered history
  low_confidence *   below `min_confidence` ("not understood, please repeat")
  not_understood *   not a phrase of the vocabulary
  too_late *         the steps it is about are no longer remembered
then answers the robot's open question if it was said within QUESTION_OPEN_S of it (credited
to the question's step, naming the question's id, questions.py), or becomes a command
(credited to the current step, sent at once) or a judgement: its onset
(not its recognition or arrival time: recognition latency must not move the credit) goes from
the teacher's clock to the simulator's (clocks.py), the teacher's reaction-delay window
(credit.py) picks the steps and the merge policy (merge.py) combines teachers; the reward goes
out unbounded (the bound g is the learner's, `feedback_bound`). Understood utterances are the
interventions, counted per episode of the step they credit and published (TeachingStats) with
each teacher's statistics.
"""

from __future__ import annotations

from collections import Counter

from voxshape.protocol import (
    ClockProbe,
    CreditedFeedback,
    HelpRequest,
    Message,
    Observation,
    TeacherNotice,
    TeacherStats,
    TeachingStats,
    Utterance,
    Vocabulary,
)
from voxshape.protocol.messages import NoticeKind
from voxshape.runtime.limits import Throttle
from voxshape.services.arbiter.clocks import TeacherClocks, answer
from voxshape.services.arbiter.config import ArbiterConfig, DelayWindow
from voxshape.services.arbiter.credit import ReactionDelay, StepTimeline
from voxshape.services.arbiter.hygiene import RateLimits, RecentIds
from voxshape.services.arbiter.meaning import NotUnderstood, interpret
from voxshape.services.arbiter.merge import Agreement, Judgement, Merged, Merger
from voxshape.services.arbiter.questions import AskedQuestion, OpenQuestions
from voxshape.services.arbiter.records import EpisodeTally, KnownRobot, KnownTeacher, TeacherTally
from voxshape.services.arbiter.replies import (
    command_feedback,
    explain,
    help_answer,
    notice,
    reward_feedback,
)

FUTURE_TOLERANCE = 0.25  # s: an onset later than its arrival by more is a clock error
EPISODES_KEPT = 16  # per robot, awaiting their final statistics
# An arbiter that has just (re)started holds utterances for robots it has not seen yet this
# long: the observations it recovers from the simulator may come after the utterances, and
# all of them are needed to know the steps the words are about.
STARTING_S = 3.0
RATE_LOOKBACK_S = 30.0  # words said this long before they arrive (what inputs recover)
MAX_HELD = 1024
PROBE_RATE, PROBE_BURST = 10.0, 20.0  # clock probes per second per teacher


class Arbiter:
    def __init__(
        self, config: ArbiterConfig, vocabulary: Vocabulary, started_at: float | None = None
    ) -> None:
        """`started_at`: when it started, on its clock (default: its first input's arrival)."""
        self.config = config
        self.vocabulary = vocabulary
        self.counters: Counter[str] = Counter()
        self.clocks = TeacherClocks()
        self.merger = Merger(config.merge, config.merge_window, config.merge_slack_steps)
        self.agreement = Agreement(config.merge_slack_steps)
        self._ids = RecentIds(config.remembered_ids)
        self._rates = RateLimits(config.utterances_per_s, config.utterances_at_once)
        self._probe_rates = RateLimits(PROBE_RATE, PROBE_BURST)
        self._notices = Throttle(config.notice_every)
        self._robots: dict[str, KnownRobot] = {}
        self._teachers: dict[str, KnownTeacher] = {}
        self._started_at = float("inf") if started_at is None else started_at
        self._held: list[tuple[Utterance, KnownTeacher, float]] = []  # recovered while starting
        self.questions = OpenQuestions()

    # -- inputs ---------------------------------------------------------------------------
    def on_observation(self, obs: Observation, received_at: float) -> list[Message]:
        """The step clock of a robot: timing, salient events, episodes."""
        self._started_at = min(self._started_at, received_at)
        robot = self._robots.get(obs.robot)
        if robot is None:
            if len(self._robots) >= self.config.max_robots:
                self.counters["rejected.too_many_robots"] += 1
                return []
            robot = self._robots[obs.robot] = KnownRobot(
                StepTimeline(self.config.history_seconds, self.config.max_history_steps)
            )
        added = robot.timeline.add(
            obs.step, obs.wall_time, obs.episode, obs.outcome == "running", obs.sim_time
        )
        if added == "restart":
            self.counters["timeline_restarted"] += 1
            robot.events.clear()
            robot.clock.reset()
        robot.clock.observe(received_at, obs.wall_time)
        if added == "late":  # recovered behind live steps, or a copy: its step timed, no more
            self.counters["late_steps"] += 1
            return []
        robot.last_seen = received_at
        if robot.events.observe(obs) is not None:
            self.counters["salient_events"] += 1
        episode = robot.episode(obs.episode)
        if obs.outcome != "running" and episode.ended_at is None:
            episode.ended_at = received_at
        return []

    def on_help(self, request: HelpRequest, received_at: float) -> list[Message]:
        """A robot asks which way: the next understood word answers it."""
        if request.robot not in self._robots:
            self.counters["rejected.question_of_unknown_robot"] += 1
            return []
        self.questions.ask(request, received_at)
        self.counters["questions"] += 1
        return []

    def on_utterance(
        self, utterance: Utterance, received_at: float, key_teacher: str | None = None
    ) -> list[Message]:
        """What an utterance becomes: feedback for the learner and a notice for the teacher."""
        teacher_id = utterance.teacher
        if key_teacher is not None and key_teacher != teacher_id:
            self.counters["rejected.teacher_mismatch"] += 1
            return []
        if self._ids.seen(utterance.id):
            self.counters["rejected.duplicate"] += 1
            return []  # the first copy was answered
        teacher = self._teacher(teacher_id)
        if teacher is None:
            return []
        return self._utterance(utterance, teacher, received_at)

    def _utterance(
        self, utterance: Utterance, teacher: KnownTeacher, received_at: float
    ) -> list[Message]:
        teacher_id, robot_id = utterance.teacher, utterance.robot
        self._started_at = min(self._started_at, received_at)
        robot = self._robots.get(robot_id)
        said_at = self.clocks.to_arbiter(teacher_id, utterance.end)
        if self._set_aside(utterance, teacher, received_at, said_at):
            return []
        if robot is not None and received_at - robot.last_seen > self.config.history_seconds:
            robot = None  # its simulator went quiet: nothing to credit
        tally = robot.tally(teacher_id) if robot is not None else TeacherTally()
        tally.utterances += 1
        pace = robot.timeline.pace if robot is not None else 1.0
        scale = self.config.time_scale(teacher_id, pace)  # for its rate, and its delays below
        # A teacher's rate is judged by when each word was said (its end, on this clock, within
        # the last RATE_LOOKBACK_S): words recovered after a restart, or queued while the arbiter
        # was frozen or the router down, arrive at once but were said at the teacher's pace.
        said_at = min(received_at, max(received_at - RATE_LOOKBACK_S, said_at))
        if not self._rates.allow(teacher_id, said_at, scale):
            return self._ignore("rate_limited", utterance, tally, received_at)
        if robot is None:
            return self._ignore("unknown_robot", utterance, tally, received_at)
        robot.changed = True
        understood = interpret(
            utterance.text, utterance.confidence, self.vocabulary, self.config.min_confidence
        )
        if isinstance(understood, NotUnderstood):
            return self._ignore(understood.reason, utterance, tally, received_at, understood.detail)
        meaning = understood.meaning
        question = self._question_answered(utterance, understood.is_command, scale)
        if question is not None:
            out, episode = self._answer(utterance, meaning.action or "stop", question)
            said = f"command {meaning.action}, the answer to {robot_id}'s question"
        elif understood.is_command:
            out, episode = self._command(
                utterance, meaning.action or "stop", teacher, robot, received_at, scale
            )
            said = f"command {meaning.action}"
        else:
            reward = meaning.reward or 0.0
            judged = self._judge(utterance, reward, teacher, robot, received_at, scale)
            if judged is None:
                return self._ignore("too_late", utterance, tally, received_at)
            out, episode = judged
            said = f"{meaning.name} ({meaning.reward:+g})"
        tally.understood += 1
        self._intervened(robot, episode, teacher_id)
        text = f"understood {utterance.text!r}: {said}"
        return [*out, self._notice(utterance, "understood", text, meaning.name)]

    def _intervened(self, robot: KnownRobot, episode: int, teacher: str) -> None:
        """An understood word, counted in the interventions of the episode it is about."""
        record = robot.episodes.get(episode)
        if record is None or record.final:  # its final statistics are out: too late for them
            self.counters["intervention_after_final"] += 1
        else:
            record.interventions[teacher] += 1

    def _set_aside(
        self, utterance: Utterance, teacher: KnownTeacher, received_at: float, said_at: float
    ) -> bool:
        """Whether a word said before this arbiter started is dropped (too old: the one
        before answered it, its steps are forgotten; no token of the rate taken) or held
        until the start is over (the robot's recovered observations may come after it)."""
        if self.clocks.to_arbiter(utterance.teacher, utterance.onset) >= self._started_at:
            return False
        if said_at < received_at - RATE_LOOKBACK_S:
            self.counters["rejected.stale"] += 1
            return True
        if received_at - self._started_at < STARTING_S and len(self._held) < MAX_HELD:
            self._held.append((utterance, teacher, received_at))
            return True
        return False

    def _release(self, now: float) -> list[Message]:
        """The held utterances, in order, once the start is over (the robot's recovered
        observations have come by then, and its steps are known)."""
        if not self._held or now - self._started_at < STARTING_S:
            return []
        held, self._held = self._held, []
        return [m for u, teacher, _ in held for m in self._utterance(u, teacher, now)]

    def on_clock_probe(
        self, probe: ClockProbe, received_at: float, now: float, key_teacher: str | None = None
    ) -> list[Message]:
        """The reply to a teacher's clock probe; keeps the estimate it reports."""
        if key_teacher is not None and key_teacher != probe.teacher:
            self.counters["rejected.teacher_mismatch"] += 1
            return []
        if self._teacher(probe.teacher) is None:
            return []
        if self._ids.seen(probe.id):
            self.counters["rejected.duplicate"] += 1
            return []
        if not self._probe_rates.allow(probe.teacher, received_at):
            self.counters["rejected.probe_rate_limited"] += 1
            return []
        if self.clocks.record(probe, received_at):
            self.counters["clock_reports"] += 1
            for robot in self._robots.values():
                robot.changed = robot.changed or probe.teacher in robot.tallies
        self.counters["clock_probes"] += 1
        return [answer(probe, received_at, now)]

    def on_tick(self, now: float) -> list[Message]:
        """Merged feedback that is due, and statistics: changed ones at most every
        `stats_every` seconds, and each episode's final ones `settle` seconds after it ended."""
        out: list[Message] = [self._feedback(m) for m in self.merger.due(now)]
        out += self._release(now)
        for robot_id, robot in self._robots.items():
            for number, episode in list(robot.episodes.items()):
                settled = (
                    episode.ended_at is not None and now - episode.ended_at >= self.config.settle
                )
                crowded = len(robot.episodes) > EPISODES_KEPT
                if not episode.final and (settled or (crowded and episode.ended_at is not None)):
                    out.append(self._stats(robot_id, robot, number, final=True))
                    episode.final = True
                if episode.final and len(robot.episodes) > EPISODES_KEPT:
                    del robot.episodes[number]
            while len(robot.episodes) > EPISODES_KEPT:  # never-ended episodes (a gap)
                robot.episodes.popitem(last=False)
            if robot.changed and now - robot.stats_sent >= self.config.stats_every:
                current = robot.timeline.latest_episode
                if current is not None:
                    out.append(self._stats(robot_id, robot, current, final=False))
                robot.changed, robot.stats_sent = False, now
        return out

    def flush(self) -> list[Message]:
        """Feedback still held by the merge policy (on shutdown)."""
        return [self._feedback(m) for m in self.merger.flush()]

    # -- views ----------------------------------------------------------------------------
    def delay_window(self, teacher: str) -> DelayWindow:
        """The reaction-delay window used now for a teacher."""
        state = self._teachers.get(teacher)
        return state.delay.window() if state else self.config.window_of(teacher)

    def delay_learned(self, teacher: str) -> bool:
        state = self._teachers.get(teacher)
        return state is not None and state.delay.learned

    @property
    def robots(self) -> list[str]:
        return list(self._robots)

    # -- helpers --------------------------------------------------------------------------
    def _teacher(self, teacher: str) -> KnownTeacher | None:
        state = self._teachers.get(teacher)
        if state is None:
            if len(self._teachers) >= self.config.max_teachers:
                self.counters["rejected.too_many_teachers"] += 1
                return None
            state = self._teachers[teacher] = KnownTeacher(
                ReactionDelay(self.config.window_of(teacher), self.config.learning)
            )
        return state

    def _command(
        self,
        utterance: Utterance,
        action: str,
        teacher: KnownTeacher,
        robot: KnownRobot,
        now: float,
        scale: float,
    ) -> tuple[list[Message], int]:
        """A command: the learner carries it out at once, and it is credited to the steps
        the teacher saw when deciding it, as a judgement is (the current step if none)."""
        self.counters["commands"] += 1
        onset = self._onset_on_sim_clock(utterance, robot, now)
        window = teacher.delay.window()
        spread = robot.timeline.spread(onset - window.hi * scale, onset - window.lo * scale)
        if spread is not None:
            return [command_feedback(utterance, action, spread.credits)], spread.episode
        latest = robot.timeline.latest_running_step()
        step, episode = latest or (robot.timeline.latest_step, robot.timeline.latest_episode)
        return [command_feedback(utterance, action, step)], episode

    def _question_answered(
        self, utterance: Utterance, is_command: bool, scale: float
    ) -> AskedQuestion | None:
        """The robot's open question a command answers (said within a few seconds of it)."""
        if not is_command:
            return None
        onset = self.clocks.to_arbiter(utterance.teacher, utterance.onset)
        return self.questions.answered_by(utterance.robot, onset, scale)

    def _answer(
        self, utterance: Utterance, action: str, question: AskedQuestion
    ) -> tuple[list[Message], int]:
        """The answer to a question (a command), credited to its step, and who gave it."""
        self.counters["answers"] += 1
        feedback = command_feedback(utterance, action, question.step, question.id)
        return [feedback, help_answer(utterance, action, question)], question.episode

    def _judge(
        self,
        utterance: Utterance,
        reward: float,
        teacher: KnownTeacher,
        robot: KnownRobot,
        now: float,
        scale: float,
    ) -> tuple[list[Message], int] | None:
        """A qualifier or the goal, credited to the steps the teacher saw (None: too late):
        the feedback to send now (by the merge policy) and the episode it is about. `scale`:
        wall seconds per second of the teacher's delays."""
        onset = self._onset_on_sim_clock(utterance, robot, now)
        polarity = 1 if reward > 0 else -1 if reward < 0 else 0
        if self.config.learning.enabled and polarity:
            self._learn_delay(teacher, utterance.robot, robot, polarity, onset, scale)
        window = teacher.delay.window()
        spread = robot.timeline.spread(onset - window.hi * scale, onset - window.lo * scale)
        if spread is None:
            return None
        if spread.clamped:
            self.counters["credited_latest_step"] += 1
        judgement = Judgement(
            robot=utterance.robot,
            teacher=utterance.teacher,
            source=utterance.id,
            reward=reward,
            weight=self.config.weight_of(utterance.teacher),
            credits=spread.credits,
            arrived=now,
        )
        self.agreement.add(judgement)
        self.counters["judgements"] += 1
        return [self._feedback(m) for m in self.merger.add(judgement)], spread.episode

    def _onset_on_sim_clock(
        self, utterance: Utterance, robot: KnownRobot, received_at: float
    ) -> float:
        if self.clocks.report(utterance.teacher) is None:
            self.counters["unsynced_teacher_utterances"] += 1
        onset = robot.clock.to_sim(self.clocks.to_arbiter(utterance.teacher, utterance.onset))
        arrival = robot.clock.to_sim(received_at)
        if onset > arrival + FUTURE_TOLERANCE:
            self.counters["onset_after_arrival"] += 1  # a clock error: the arrival is the bound
            return arrival
        return onset

    def _learn_delay(
        self,
        teacher: KnownTeacher,
        robot_id: str,
        robot: KnownRobot,
        polarity: int,
        onset: float,
        scale: float,
    ) -> None:
        """Offers a judgement as a candidate reaction to each salient event of its sign seen
        shortly before its onset (within a step after it too: clocks are never exact); delays
        in the teacher's seconds (`scale` wall seconds each)."""
        within = self.config.learning.pair_within * scale
        for event in robot.events.seen_within(polarity, onset - within, onset + 0.05 * scale):
            if teacher.delay.add((robot_id, event.step), (onset - event.reference) / scale):
                self.counters["delay_candidates"] += 1

    def _feedback(self, merged: Merged) -> CreditedFeedback:
        self.counters["feedback"] += 1
        return reward_feedback(merged)

    def _ignore(
        self,
        reason: NoticeKind,
        utterance: Utterance,
        tally: TeacherTally,
        now: float,
        detail: str = "",
    ) -> list[Message]:
        self.counters[f"rejected.{reason}"] += 1
        tally.ignored += 1
        if reason == "rate_limited" and not self._notices.due((utterance.teacher, reason), now):
            return []
        why = explain(
            reason, utterance, detail, self.vocabulary, self.config.utterances_per_s, self._robots
        )
        return [self._notice(utterance, reason, why, None)]

    def _notice(
        self, utterance: Utterance, kind: NoticeKind, text: str, meaning: str | None
    ) -> TeacherNotice:
        self.counters[f"notices.{kind}"] += 1
        return notice(utterance, kind, text, meaning)

    def _stats(self, robot_id: str, robot: KnownRobot, number: int, final: bool) -> TeachingStats:
        episode = robot.episodes.get(number) or EpisodeTally()
        teachers = []
        for teacher_id, tally in list(robot.tallies.items())[:64]:
            state = self._teachers.get(teacher_id)
            window = state.delay.window() if state else self.config.window_of(teacher_id)
            clock = self.clocks.report(teacher_id)
            teachers.append(
                TeacherStats(
                    teacher=teacher_id,
                    interventions=episode.interventions[teacher_id],
                    utterances=tally.utterances,
                    understood=tally.understood,
                    ignored=tally.ignored,
                    compared=self.agreement.compared[robot_id, teacher_id],
                    agreement=self.agreement.share(robot_id, teacher_id),
                    delay=window.centre,
                    delay_width=window.width,
                    delay_learned=state is not None and state.delay.learned,
                    clock_offset=clock.offset if clock else None,
                    clock_rtt=min(clock.rtt, 60.0) if clock else None,
                )
            )
        return TeachingStats(
            robot=robot_id,
            episode=number,
            final=final,
            interventions=sum(episode.interventions.values()),
            teachers=tuple(teachers),
        )
