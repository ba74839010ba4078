"""The chaos and soak harness, shared by tests/test_chaos.py and benchmarks/{chaos,soak}.py.

A whole session as a person runs it: `voxshape up` (the launcher, which restarts a service that
dies, as compose's `restart` says) with the mock speech engine and the logger, plus one
simulated teacher per robot, all in a working directory of its own (its runs/<session>/).

session.py   the session: the launcher's process, the teachers, the pids of the services
monkey.py    kills or freezes services by pid on a schedule; were they restarted, left alone
verdict.py   from the event log, the checkpoints and the counters: did every word the arbiter
             understood reach its learner exactly once, did every learner converge
replay.py    does a replay of the event log show what the live recording shows
chaos.py     a whole chaos session, and the learning each learner kill lost

Its bus node is the benchmarks' Probe (benchmarks/probe.py). Every wait is bounded; only
processes started here are signalled, by pid.
"""

from benchmarks.harness.chaos import LearnerLoss, run_chaos
from benchmarks.harness.monkey import Fault, Monkey, fault_table, random_schedule
from benchmarks.harness.session import Session
from benchmarks.harness.verdict import Verdict, verdict_table

__all__ = [
    "Fault",
    "LearnerLoss",
    "Monkey",
    "Session",
    "Verdict",
    "fault_table",
    "random_schedule",
    "run_chaos",
    "verdict_table",
]
