"""The learner: SARSA(lambda) with dynamic reward shaping (the paper's Algorithm 1)."""
