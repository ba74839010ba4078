"""The speech benchmark: `.venv/bin/python -m benchmarks.speech` (__main__.py says what it
measures and how). scoring.py runs an engine over WAV clips as the service would and scores
it; the engines' tests score them with it too."""
