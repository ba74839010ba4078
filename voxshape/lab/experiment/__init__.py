"""Experiments: the paper's tables and figure, with the in-process cores (issue 8)."""
