"""Experiments (`voxshape experiment`, `voxshape train`): the paper's tables and figure and
the sweeps, each run stepping the services' cores together in one process (inprocess.py), and
the same run over the bus to compare with (distributed.py)."""
