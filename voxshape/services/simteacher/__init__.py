"""The simulated teacher: a scripted person for experiments and tests (issue 8)."""
