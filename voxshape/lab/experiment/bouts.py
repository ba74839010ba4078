"""Bump bouts: stretches of robot time spent bumping into something again and again (a robot
pinned to a wall), measured per episode for the experiments' reports.

A bout is a run of bumps (steps whose move hit something) each within `GAP_S` robot seconds of
the one before; it lasts from its first bump to the end of its last bump's step. Bouts of
`MIN_BOUT_S` or more are a robot stuck against a wall rather than one grazing a corner."""

from __future__ import annotations

GAP_S = 2.0  # robot seconds between two bumps of one bout, at most
MIN_BOUT_S = 10.0  # a bout this long or longer counts


class BumpBouts:
    """Robot seconds in long bump bouts, fed one step at a time."""

    def __init__(self, period: float) -> None:
        self.period = period
        self.total = 0.0  # seconds in bouts of MIN_BOUT_S or more, ended so far
        self._bout: tuple[float, float] | None = None  # (first bump, last bump)

    def step(self, t: float, collided: bool) -> None:
        """The step at robot time `t` (seconds) and whether it bumped."""
        if not collided:
            if self._bout is not None and t - self._bout[1] > GAP_S:
                self._close()
            return
        if self._bout is None or t - self._bout[1] > GAP_S:
            self._close()
            self._bout = (t, t)
        else:
            self._bout = (self._bout[0], t)

    def end(self) -> float:
        """Ends the episode; returns its seconds in long bouts (and starts the next at 0)."""
        self._close()
        total, self.total = self.total, 0.0
        return total

    def _close(self) -> None:
        if self._bout is not None:
            length = self._bout[1] - self._bout[0] + self.period
            if length >= MIN_BOUT_S:
                self.total += length
            self._bout = None
