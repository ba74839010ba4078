"""`voxshape teach`: a person's end of a session.

sources.py  what the teacher gives: WAV files, a microphone, typed words (pure, but the mic)
board.py    what the teacher sees: the robot's status and questions, what was understood (pure)
node.py     the client on the bus
"""
