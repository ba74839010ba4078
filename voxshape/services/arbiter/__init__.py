"""The feedback arbiter: the only place where words become numbers.

meaning.py   utterance -> vocabulary meaning, confidence gate
clocks.py    teacher clocks (NTP-style offsets) and the simulator's clock
credit.py    step timing, reaction-delay windows (learnt per teacher) -> credited steps
merge.py     several teachers: sum, mean, majority; agreement between them
hygiene.py   duplicates, rate limits, notice throttling
questions.py robots' open questions, answered by the next understood word
records.py   what it keeps of each robot and teacher
replies.py   the messages it sends: credited feedback, answers, notices
arbiter.py   the core tying them together (no bus)
node.py      `voxshape arbiter` on the bus
scripted.py  a scripted robot and teacher for measuring credit accuracy without the bus
"""
