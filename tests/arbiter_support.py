"""What the arbiter's core tests share (tests/test_arbiter*.py): an arbiter on made-up,
exact times, and what it sent."""

from __future__ import annotations

from voxshape.protocol import (
    CreditedFeedback,
    TeacherNotice,
)
from voxshape.protocol.vocabulary import load_vocabulary
from voxshape.services.arbiter.arbiter import Arbiter
from voxshape.services.arbiter.config import (
    ArbiterConfig,
)
from voxshape.services.arbiter.scripted import (
    scripted_observation,
)

T0 = 1_700_000_000.0  # wall time of step 0


PERIOD = 0.1


VOCABULARY = load_vocabulary()


def shown(step: int) -> float:
    return T0 + step * PERIOD


def arbiter(steps: int = 100, **settings) -> Arbiter:
    """An arbiter that has seen robot r1 step at exactly 10 Hz, steps 0..steps-1."""
    a = Arbiter(ArbiterConfig(**settings), VOCABULARY)
    for k in range(steps):
        a.on_observation(scripted_observation("r1", k, shown(k)), shown(k))
    return a


def feedback(messages: list) -> list[CreditedFeedback]:
    return [m for m in messages if isinstance(m, CreditedFeedback)]


def notices(messages: list) -> list[TeacherNotice]:
    return [m for m in messages if isinstance(m, TeacherNotice)]


def credits(message: CreditedFeedback) -> dict[int, float]:
    return {c.step: round(c.weight, 6) for c in message.credits}
