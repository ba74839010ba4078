"""`voxshape speech`: teachers' audio in, utterances out.

audio.py      PCM and WAV helpers (16 kHz mono int16), shared with the teacher client
segmenter.py  voice activity and endpointing of one audio stream (pure)
streams.py    every teacher's streams: ordering, clocks, limits, segments (pure)
recognizer.py the recognizer interface; engines.py how an engine is chosen
cascade.py    the default engine: pocketsphinx, then Whisper on what it is not sure of
pocketsphinx_engine.py, whisper_engine.py, vosk_engine.py, mock.py   the engines
transcriber.py  segments or said text -> Utterance messages (pure)
node.py       the service on the bus
bench.py      accuracy, false accepts and speed on the WAV fixtures
"""
