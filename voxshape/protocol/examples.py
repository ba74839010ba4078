"""One realistic message of each type, with the key it travels on: for docs, checks and tests."""

from __future__ import annotations

import time

from voxshape.protocol.keys import robot_key, teacher_key
from voxshape.protocol.messages import (
    Action,
    Alternative,
    AudioChunk,
    ClockProbe,
    ClockReply,
    Credit,
    CreditedFeedback,
    EpisodeEvent,
    HelpAnswer,
    HelpRequest,
    LearningSummary,
    Learnt,
    Message,
    Observation,
    Placed,
    RobotLimits,
    Said,
    TeacherNotice,
    TeacherStats,
    TeachingStats,
    Utterance,
)


def example_messages(
    session: str, robot: str = "r1", teacher: str = "ana"
) -> list[tuple[str, Message]]:
    now = time.time()
    said = _utterance(robot, teacher, now)
    return [
        *_sim_examples(session, robot, now),
        *_speech_examples(session, robot, teacher, said, now),
        *_learning_examples(session, robot, teacher, said),
        *_arbiter_examples(session, robot, teacher, said, now),
        *_help_examples(session, robot, teacher, said),
    ]


def _utterance(robot: str, teacher: str, now: float) -> Utterance:
    """What the teacher said, as recognized: the feedback and the notice below refer to it."""
    return Utterance(
        teacher=teacher,
        robot=robot,
        text="muy bien",
        confidence=0.87,
        onset=now - 1.2,
        end=now - 0.7,
        recognized_at=now - 0.4,
        engine="mock",
        language="es",
        alternatives=(Alternative(text="muy mal", confidence=0.08),),
    )


def _sim_examples(session: str, robot: str, now: float) -> list[tuple[str, Message]]:
    """The simulator's loop: its robot's limits, an observation, the action chosen for it,
    an episode's end."""
    return [
        (
            robot_key(session, robot, "limits"),
            RobotLimits(robot=robot, max_speed=0.7, max_turn=1.745),
        ),
        (
            robot_key(session, robot, "obs"),
            Observation(
                robot=robot,
                episode=3,
                step=412,
                episode_step=57,
                sim_time=41.2,
                wall_time=now,
                x=1.25,
                y=-0.5,
                theta=0.78,
                v=0.4,
                omega=-0.2,
                laser=(4.0,) * 180,
                sonar=(1.5,) * 8,
                reward=-1.0,
                goal_distance=4.3,
                goal_bearing=0.35,
                outcome="running",
                collided=False,
            ),
        ),
        (
            robot_key(session, robot, "action"),
            Action(
                robot=robot, episode=3, step=412, discrete=1, v=0.45, omega=0.1, chooser="policy"
            ),
        ),
        (
            robot_key(session, robot, "episode"),
            EpisodeEvent(
                robot=robot,
                episode=3,
                step=460,
                kind="goal",
                episode_steps=105,
                sim_time=46.0,
                wall_time=now,
                env_return=-4.0,
            ),
        ),
    ]


def _speech_examples(
    session: str, robot: str, teacher: str, said: Utterance, now: float
) -> list[tuple[str, Message]]:
    """A teacher's voice: the audio, what speech recognition made of it, and the text said."""
    return [
        (
            teacher_key(session, teacher, "audio"),
            AudioChunk(
                teacher=teacher,
                robot=robot,
                stream="mic-1",
                seq=17,
                sample_rate=16000,
                pcm=bytes(1600),
                capture_time=now - 0.05,
                final=False,
            ),
        ),
        (teacher_key(session, teacher, "utterance"), said),
        (
            teacher_key(session, teacher, "said"),
            Said(
                teacher=teacher,
                robot=robot,
                text="muy bien",
                language="es",
                onset=now - 1.2,
                end=now - 0.7,
            ),
        ),
    ]


def _learning_examples(
    session: str, robot: str, teacher: str, said: Utterance
) -> list[tuple[str, Message]]:
    """What reaches the learner and what it reports: credited feedback, a learning summary."""
    return [
        (
            robot_key(session, robot, "feedback"),
            CreditedFeedback(
                robot=robot,
                kind="reward",
                reward=50.0,
                command=None,
                credits=(Credit(step=405, weight=0.6), Credit(step=406, weight=0.4)),
                sources=(said.id,),
                teachers=(teacher,),
            ),
        ),
        (
            robot_key(session, robot, "learning"),
            LearningSummary(
                robot=robot,
                episode=3,
                step=412,
                state=17,
                states=64,
                q_values=(0.0, 12.5, -3.0, 4.25, 1.0),
                td_error=0.75,
                epsilon=0.1,
                reward=-1.0,
                episode_return=37.5,
            ),
        ),
    ]


def _arbiter_examples(
    session: str, robot: str, teacher: str, said: Utterance, now: float
) -> list[tuple[str, Message]]:
    """The arbiter's messages: a clock exchange, a notice and a robot's teaching statistics."""
    skew = 4.2  # this teacher's clock is 4.2 s behind the arbiter's
    probe = ClockProbe(teacher=teacher, t0=now - skew, offset=4.1998, rtt=0.0006)
    return [
        (teacher_key(session, teacher, "clock"), probe),
        (
            teacher_key(session, teacher, "clock-reply"),
            ClockReply(teacher=teacher, probe=probe.id, t0=probe.t0, t1=now + 3e-4, t2=now + 4e-4),
        ),
        (
            teacher_key(session, teacher, "notice"),
            TeacherNotice(
                teacher=teacher,
                robot=robot,
                utterance=said.id,
                kind="low_confidence",
                meaning=None,
                text="not used: heard 'good' with confidence 0.30, below 0.50; say it again",
            ),
        ),
        (
            robot_key(session, robot, "teaching"),
            TeachingStats(
                robot=robot,
                episode=3,
                final=False,
                interventions=4,
                teachers=(
                    TeacherStats(
                        teacher=teacher,
                        interventions=4,
                        utterances=31,
                        understood=27,
                        ignored=4,
                        compared=0,
                        agreement=None,
                        delay=1.35,
                        delay_width=0.2,
                        delay_learned=True,
                        clock_offset=probe.offset,
                        clock_rtt=probe.rtt,
                    ),
                ),
            ),
        ),
    ]


def _help_examples(
    session: str, robot: str, teacher: str, said: Utterance
) -> list[tuple[str, Message]]:
    """The robot asks which way (learner), and who answered (arbiter); a teacher says a real
    robot is placed at its start."""
    question = HelpRequest(
        robot=robot, episode=3, step=405, reason="stuck", detail="stuck for 10 s", x=1.2, y=-0.4
    )
    return [
        (robot_key(session, robot, "help"), question),
        (
            robot_key(session, robot, "answer"),
            HelpAnswer(
                robot=robot,
                question=question.id,
                step=question.step,
                teacher=teacher,
                meaning="left",
                utterance=said.id,
            ),
        ),
        # A real robot waiting between episodes (voxshape ros2 --reset wait): it is back.
        (teacher_key(session, teacher, "placed"), Placed(teacher=teacher, robot=robot)),
        # The demo says the robot has learnt its task (and it goes on).
        (
            robot_key(session, robot, "learnt"),
            Learnt(robot=robot, episode=4, episodes=5, robot_seconds=52.5, task="task 1"),
        ),
    ]
