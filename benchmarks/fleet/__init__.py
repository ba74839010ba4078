"""A class teaches a fleet: N robots at real time (10 Hz) and M teachers in one session, measured.

    .venv/bin/python -m benchmarks.fleet --points 1x1,5x10,10x10,20x40 --seconds 30
    .venv/bin/python -m benchmarks.fleet --robots 1,5,10,20 --teachers 1,10,40 --json

Each point (N robots, M teachers; `--robots` x `--teachers`, or the pairs of `--points`) is a
session of its own (a LoopbackSession), on loopback, with its own session id and free ports:
compose.yaml's router and services but the logger: ONE simulator process for the N robots
(`voxshape sim --robot r1 --robot r2 ...`; a world holds 28 robots, so past 28 one simulator
for each 28, `--robots-per-sim`), ONE learner process
serving all N, the arbiter, the speech service with the mock engine and the web page's
gateway (`voxshape web`). The M teachers are spread over the robots (teacher i teaches robot
i mod N): half of them, rounded down, are simulated people (`voxshape sim-teacher`, its default
profile: at most 4 words a robot minute, at salient moments), the others browsers
(`--browsers` sets their number): WebSocket clients of the page that speak its own protocol
(voxshape/services/web/static/net.js and app.js): log in, five clock probes 100 ms apart and one
every 30 s, `watch` their robot, read every map frame the gateway sends (all robots' at up to
10 Hz each), and press one of the page's word buttons every `--word-every` seconds on average
(exponential gaps). The browsers run in processes of the harness, at most 10 in each.

session.py    the point's processes; clients.py the simulated people and the browsers;
measure.py    the window's CPU reading, a point's figures, what ran out first;
profiling.py  the limiting process's profile; report.py the tables and the plot

Measured over `--seconds` after `--warmup` (all wall clock, one machine):

- CPU (percent of one core) and resident memory of every process, psutil; the whole
  machine's busy share, so other work on it shows;
- each robot's achieved step rate against 10 Hz, from its observations on the bus (steps
  advanced over the simulator's wall time), the share of steps it took without a fresh
  action (none newer than the simulator's 0.5 s: it stood still), and observation -> the
  learner's action;
- a word's latency: said -> understood notice -> credited feedback, p50/p99 with the number
  of words (a p99 of fewer than 100 is their maximum, and printed so), matched by utterance
  id (a simulated person: said = its `Said` left it, understood = the arbiter's notice on the
  bus; a browser: said = the `say` frame was sent, understood = the page got the notice;
  feedback = the arbiter's credited feedback naming the utterance, on the bus). The words are
  text: the mock engine "hears" them after `--mock-latency`, no recognition is measured;
- the page's frames: a map frame's age when it reaches the browser (now - the simulator's
  wall time of that observation), and frames a browser got a second;
- words lost: said within the window (bar its last 3 s) and never understood.

It names the first resource to run out (a process at 85% of a core or more, or the
machine's cores), and profiles the limiting process of the first point where something ran
out (else of the last point): py-spy `--gil` on the live process if it is installed
(`--py-spy`, else on PATH), else cProfile of an in-process equivalent (simulator, learner,
arbiter or gateway), else none. Every process it starts is ended by pid, on Ctrl-C and on
failure too.
"""
