"""The clocks the arbiter relates. Credit is decided on the simulator's clock, where the step
timing is (each Observation's `wall_time`); utterance times come on their teacher's clock.

teacher clock --(offset reported by the teacher)--> arbiter clock --(SimulatorClock)--> sim clock

- Teacher clocks, NTP style: a teacher sends a ClockProbe (t0, its clock) on its `clock` key;
  the arbiter answers a ClockReply with t1 (probe received) and t2 (reply sent) on its own
  clock; the teacher, receiving it at t3, computes offset = ((t1 - t0) + (t2 - t3)) / 2 and
  rtt = (t3 - t0) - (t2 - t1), keeps the exchange with the lowest rtt (the least queueing, so
  the least asymmetry; the error is at most rtt / 2) and reports it in its next probe.
  `voxshape/runtime/clock.py: sync_clock` is that client. The arbiter uses the latest report.
- The simulator's clock: the arbiter receives each observation a little after its wall_time.
  offset = min over the latest observations of (arrival on the arbiter's clock - wall_time)
  is the clock difference plus the smallest transport delay (about 0.2 ms on one host). The
  teacher watches the robot through the same bus, so that delay is part of what they see.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from voxshape.protocol import ClockProbe, ClockReply


def answer(probe: ClockProbe, received_at: float, now: float) -> ClockReply:
    """The reply to a probe received at `received_at` and answered at `now` (arbiter clock)."""
    return ClockReply(
        teacher=probe.teacher, probe=probe.id, t0=probe.t0, t1=received_at, t2=max(now, received_at)
    )


@dataclass(frozen=True)
class ClockReport:
    offset: float  # arbiter clock - teacher clock, seconds
    rtt: float  # of the exchange it came from: the offset is within +-rtt/2
    reported_at: float  # arbiter clock


class TeacherClocks:
    """The latest clock estimate each teacher reported."""

    def __init__(self) -> None:
        self._reports: dict[str, ClockReport] = {}

    def record(self, probe: ClockProbe, now: float) -> bool:
        """Keeps the estimate a probe carries (a first probe carries none); True if it did."""
        if probe.offset is None or probe.rtt is None:
            return False
        self._reports[probe.teacher] = ClockReport(probe.offset, probe.rtt, now)
        return True

    def report(self, teacher: str) -> ClockReport | None:
        return self._reports.get(teacher)

    def to_arbiter(self, teacher: str, t: float) -> float:
        """A time on the teacher's clock, on the arbiter's (unchanged if never synced)."""
        report = self._reports.get(teacher)
        return t if report is None else t + report.offset

    def forget(self, teacher: str) -> None:
        self._reports.pop(teacher, None)


class SimulatorClock:
    """One simulator's clock seen from the arbiter: a sliding minimum over `window`
    observations of (arrival time - wall_time), kept in O(1) per observation."""

    def __init__(self, window: int = 256) -> None:
        self.window = window
        self._count = 0
        self._minima: deque[tuple[int, float]] = deque()  # increasing values, within window

    def observe(self, received_at: float, wall_time: float) -> None:
        lag = received_at - wall_time
        while self._minima and self._minima[-1][1] >= lag:
            self._minima.pop()
        self._minima.append((self._count, lag))
        self._count += 1
        while self._minima[0][0] <= self._count - 1 - self.window:
            self._minima.popleft()

    @property
    def offset(self) -> float:
        """Arbiter clock - simulator clock (0 before any observation)."""
        return self._minima[0][1] if self._minima else 0.0

    def to_sim(self, t: float) -> float:
        """A time on the arbiter's clock, on the simulator's."""
        return t - self.offset

    def reset(self) -> None:
        self._minima.clear()
