"""The world every service draws or simulates: maps (tasks and map files) and the robot's
model. Shared by the simulator, the logger, the web page, the simulated teacher and the
experiments; it imports no service."""
