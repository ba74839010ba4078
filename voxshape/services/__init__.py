"""The services: one package per process of compose.yaml but the router (which is
voxshape/deploy/router.py). Each is a pure core (no zenoh) and a node that runs it on the bus,
and imports only itself and the floors below it (the shared floor, the runtime, the protocol).

arbiter     words -> credited rewards and commands (delay correction, several teachers)
learner     SARSA(lambda) with dynamic rewards, one agent per robot
logger      the durable event log and the rerun recording
ros2        a real ROS 2 robot on the bus (rmw_zenoh's wire format)
sim         the PyBullet simulator of the robots and their maps
speech      teacher audio -> utterances
teacher     `voxshape teach`, a person's terminal
web         the web gateway: a teacher's page in a browser
simteacher  the simulated person (experiments, the demo)
"""
