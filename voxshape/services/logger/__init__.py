"""The logger: a session's durable event log, its rerun recording and replays.

eventlog.py (append/read raw records), decoding.py (records -> messages), tally.py (where each
robot stands), recording.py (messages -> rerun), replay.py (`voxshape replay`, and the live
renderer), node.py (`voxshape logger`), view.py (`voxshape view`), run.py (the run directory
and session.json). `voxshape report` is voxshape/lab/report/, above the services.
"""
