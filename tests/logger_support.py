"""Support for the logger's tests: a scripted session (a robot driving straight episodes on
task 1, with known returns, a teacher's utterance and credited feedback at known steps, and the
arbiter's count of interventions per episode), and reading a recording back with rerun's
RrdReader."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from voxshape.protocol import (
    Action,
    Credit,
    CreditedFeedback,
    EpisodeEvent,
    LearningSummary,
    Message,
    Observation,
    TeachingStats,
    Utterance,
    encode,
    robot_key,
    teacher_key,
)
from voxshape.services.logger.eventlog import EventLogWriter, EventRecord
from voxshape.world.maps import Map, load_map

TIMELINES = ("step", "episode", "sim_time", "wall_time")
# A map that is not task 1: its shortest time is 19 s where task 1's is 10.3 s.
LONG_ROOM = Path(__file__).parent / "fixtures" / "maps" / "long-room.toml"


@dataclass
class Script:
    messages: list[tuple[str, Message]] = field(default_factory=list)
    returns: dict[int, float] = field(default_factory=dict)  # episode -> env return
    observations: int = 0
    feedback_credited_step: int = -1
    feedback_arrival_step: int = -1  # the robot's latest step when the feedback arrives
    feedback_reward: float = 0.0


def scripted_session(
    session: str,
    episodes: int = 3,
    steps: int = 20,
    robot: str = "r1",
    feedback_episode: int = 1,
) -> Script:
    """`episodes` episodes of `steps` steps each; the arbiter's final count of interventions
    of each episode comes during the next (the last one's never)."""
    m = load_map("1")
    script = Script()
    add = script.messages.append
    step = 0
    for episode in range(episodes):
        x, y, theta = m.start.x, m.start.y, m.start.theta
        add((robot_key(session, robot, "episode"), episode_event(robot, episode, step)))
        if episode > 0:  # the arbiter settles an episode's count during the next one
            count = TeachingStats(
                robot=robot,
                episode=episode - 1,
                final=True,
                interventions=int(episode - 1 == feedback_episode),
                teachers=(),
            )
            add((robot_key(session, robot, "teaching"), count))
        total = 0.0
        for k in range(steps + 1):
            last = k == steps
            reward = 0.0 if k == 0 else (100.0 if last and episode % 2 == 0 else -1.0)
            total += reward
            outcome = ("goal" if episode % 2 == 0 else "timeout") if last else "running"
            seen = observation(m, robot, (episode, step, k), (x, y, theta), reward, outcome)
            add((robot_key(session, robot, "obs"), seen))
            script.observations += 1
            if episode == feedback_episode and k == steps // 2:
                add_feedback(script, session, robot, step)
            if not last:
                add((robot_key(session, robot, "action"), action(robot, episode, step)))
            learnt = learning(robot, (episode, step, k), last, reward, total)
            add((robot_key(session, robot, "learning"), learnt))
            x += 0.03 * math.cos(theta)
            y += 0.03 * math.sin(theta)
            step += 1
        kind = "goal" if episode % 2 == 0 else "timeout"
        ended = episode_event(robot, episode, step - 1, kind, steps, total)
        add((robot_key(session, robot, "episode"), ended))
        script.returns[episode] = total
    return script


T0 = 1.7e9  # the scripted session's wall time at step 0


def episode_event(
    robot: str, episode: int, step: int, kind: str = "start", steps: int = 0, total: float = 0.0
) -> EpisodeEvent:
    """An episode's start (at `step`) or its end (`kind`, after `steps`, returning `total`)."""
    return EpisodeEvent(
        robot=robot,
        episode=episode,
        step=step,
        kind=kind,
        episode_steps=steps,
        sim_time=step * 0.1,
        wall_time=T0 + (step + (kind != "start")) * 0.1,
        env_return=total,
    )


def observation(
    m: Map,
    robot: str,
    when: tuple[int, int, int],
    pose: tuple[float, float, float],
    reward: float,
    outcome: str,
) -> Observation:
    """What the robot sees at `when` (episode, step, step of the episode) from `pose`."""
    (episode, step, k), (x, y, theta) = when, pose
    a = math.atan2(m.goal_y - y, m.goal_x - x)
    return Observation(
        robot=robot,
        episode=episode,
        step=step,
        episode_step=k,
        sim_time=step * 0.1,
        wall_time=T0 + step * 0.1,
        x=x,
        y=y,
        theta=theta,
        v=0.3,
        omega=0.0,
        laser=tuple(2.0 + 0.01 * i for i in range(180)),
        sonar=(1.0,) * 8,
        reward=reward,
        goal_distance=math.hypot(m.goal_x - x, m.goal_y - y),
        goal_bearing=math.remainder(a - theta, math.tau),
        outcome=outcome,
        collided=False,
    )


def add_feedback(script: Script, session: str, robot: str, step: int) -> None:
    """ana's "good" at `step`, credited two steps back."""
    said = Utterance(
        teacher="ana",
        robot=robot,
        text="good",
        confidence=0.9,
        onset=T0,
        end=T0 + 0.3,
        recognized_at=T0 + 0.4,
        engine="mock",
        language="en",
        alternatives=(),
    )
    script.messages.append((teacher_key(session, "ana", "utterance"), said))
    script.feedback_credited_step = step - 2
    script.feedback_arrival_step = step
    script.feedback_reward = 10.0
    credited = CreditedFeedback(
        robot=robot,
        kind="reward",
        reward=10.0,
        command=None,
        credits=(Credit(step=step - 2, weight=1.0),),
        sources=(said.id,),
        teachers=("ana",),
    )
    script.messages.append((robot_key(session, robot, "feedback"), credited))


def action(robot: str, episode: int, step: int) -> Action:
    return Action(
        robot=robot,
        episode=episode,
        step=step,
        discrete=1,
        v=0.3,
        omega=0.0,
        chooser="policy",
    )


def learning(
    robot: str, when: tuple[int, int, int], last: bool, reward: float, total: float
) -> LearningSummary:
    (episode, step, k) = when
    return LearningSummary(
        robot=robot,
        episode=episode,
        step=step,
        state=k % 3,
        states=min(3, k + 1) + episode,
        q_values=(0.0, 1.0, -1.0, 0.5, 0.25) if not last else (),
        td_error=0.1,
        epsilon=0.1,
        reward=reward,
        episode_return=total,
    )


def write_script(path, session: str, script: Script, t0: float = 1.7e9) -> list[EventRecord]:
    """Writes the script's messages as an event log (1 ms apart); returns the records."""
    records = [
        EventRecord(t0 + 0.001 * i, key, "put", encode(message))
        for i, (key, message) in enumerate(script.messages)
    ]
    with EventLogWriter(path, session) as writer:
        for record in records:
            writer.append(record)
    return records


def no_analytics(tmp_path, monkeypatch=None) -> dict[str, str]:
    """Environment under which rerun's CLI keeps its config (analytics off) in tmp_path."""
    config, data = tmp_path / "xdg-config", tmp_path / "xdg-data"
    (config / "rerun").mkdir(parents=True, exist_ok=True)
    (config / "rerun" / "analytics.json").write_text('{"analytics_enabled": false}')
    env = {"XDG_CONFIG_HOME": str(config), "XDG_DATA_HOME": str(data)}
    if monkeypatch is not None:
        for k, v in env.items():
            monkeypatch.setenv(k, v)
    return env


def rows(path, entity: str | None = None) -> dict[str, list[tuple]]:
    """The temporal rows of a recording per entity: (step, episode, sim_time ns, wall_time ns,
    then each component's values), in step order; rerun's own log_time and row ids left out."""
    import pyarrow as pa
    from rerun.chunk import RrdReader

    stream = RrdReader(path).stream()
    if entity is not None:
        stream = stream.filter(content=entity)
    out: dict[str, list[tuple]] = {}
    for chunk in stream.filter(is_static=False):
        batch = chunk.to_record_batch()
        names = [f.name for f in batch.schema]
        index = []
        for t in TIMELINES:
            if t in names:
                column = batch.column(t)
                if pa.types.is_timestamp(column.type) or pa.types.is_duration(column.type):
                    column = column.cast(pa.int64())
                index.append(column.to_pylist())
            else:
                index.append([None] * batch.num_rows)
        data = sorted(n for n in names if ":" in n)
        values = [batch.column(n).to_pylist() for n in data]
        table = out.setdefault(chunk.entity_path, [])
        for i in range(batch.num_rows):
            table.append(tuple(col[i] for col in index) + tuple(_frozen(v[i]) for v in values))
    return {
        k: sorted(v, key=lambda r: (-1 if r[0] is None else r[0], repr(r))) for k, v in out.items()
    }


def _frozen(value):
    if isinstance(value, list):
        return tuple(_frozen(v) for v in value)
    return value


def listening_on(port: int) -> set[str]:
    """The IPv4 addresses a TCP socket listens on at `port` (from /proc/net/tcp)."""
    found = set()
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        local, state = line.split()[1], line.split()[3]
        address, hex_port = local.split(":")
        if state == "0A" and int(hex_port, 16) == port:  # 0A: LISTEN
            found.add(".".join(str(int(address[i : i + 2], 16)) for i in (6, 4, 2, 0)))
    return found
