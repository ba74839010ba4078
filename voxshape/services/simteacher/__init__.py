"""The simulated teacher (`voxshape sim-teacher`): a person who watches a robot and judges or
steers it by voice, at most a few words a robot minute, late and sometimes wrong; its core is
teacher.py, also stepped in-process by the experiments."""
