"""A Gymnasium environment over the simulator core: one robot, one task.

    env = NavigationEnv(task="1")  # or gym.make(MAKE_ID, task="1"), no import needed
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(np.array([0.5, 0.0], np.float32))

Observation (a Dict):
    laser  (180,) metres, beams from the robot's right (-90 deg) to its left (+90 deg)
    sonar  (8,)   metres, the rear ring from the left side round the back to the right side
    goal   (2,)   straight-line distance (m) and bearing (rad, + = to the left) to the goal
    velocity (2,) the (v, omega) the robot moved with in the last step
Action: Box([-max_speed, -max_turn], [max_speed, max_turn]): forward speed (m/s) and turn rate
(rad/s, + = left); values outside are clipped. Reward: R_RL (see
voxshape.services.sim.task.Rewards). Episodes terminate at the goal or on collision (with
`collision="end"`) and are truncated at the map's timeout. Seeded runs are bit-identical.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from voxshape.services.sim.task import Reading, SimConfig, Simulation
from voxshape.world.maps import load_map


class NavigationEnv(gym.Env):
    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self, task: str = "1", config: SimConfig | None = None, render_mode: str | None = None
    ) -> None:
        self.map = load_map(task)
        self.config = config or SimConfig()
        self.sim = Simulation(self.map, ("robot",), self.config)
        self.render_mode = render_mode
        m = self.config.model
        diagonal = math.hypot(self.map.width, self.map.height)
        f32 = np.float32
        self.observation_space = spaces.Dict(
            {
                "laser": spaces.Box(m.laser_min, m.laser_max, (m.laser_beams,), f32),
                "sonar": spaces.Box(m.sonar_min, m.sonar_max, (len(m.sonar_angles),), f32),
                "goal": spaces.Box(
                    np.array([0.0, -math.pi], f32), np.array([diagonal, math.pi], f32)
                ),
                "velocity": spaces.Box(
                    np.array([-m.max_speed, -m.max_turn], f32),
                    np.array([m.max_speed, m.max_turn], f32),
                ),
            }
        )
        self.action_space = spaces.Box(
            np.array([-m.max_speed, -m.max_turn], f32), np.array([m.max_speed, m.max_turn], f32)
        )
        self._last: Reading | None = None
        self._trajectory: list[tuple[float, float]] = []

    def _observation(self, r: Reading) -> dict[str, np.ndarray]:
        return {
            "laser": r.laser.astype(np.float32),
            "sonar": r.sonar.astype(np.float32),
            "goal": np.array([r.goal_distance, r.goal_bearing], np.float32),
            "velocity": np.array([r.v, r.omega], np.float32),
        }

    def _info(self, r: Reading) -> dict[str, Any]:
        return {
            "pose": (r.pose.x, r.pose.y, r.pose.theta),
            "outcome": r.outcome,
            "collided": r.collided,
            "episode_step": r.episode_step,
            "episode_time": r.episode_step * self.config.control_period,
        }

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict]:
        super().reset(seed=seed)
        if seed is not None:
            self.sim.seed(seed)
        self._last = self.sim.reset("robot")
        self._trajectory = [(self._last.pose.x, self._last.pose.y)]
        return self._observation(self._last), self._info(self._last)

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict]:
        if self._last is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        if self._last.outcome != "running":
            raise gym.error.ResetNeeded(f"the episode ended ({self._last.outcome}): reset()")
        v, omega = (float(a) for a in np.asarray(action, dtype=np.float64).reshape(2))
        r = self.sim.step({"robot": (v, omega)})["robot"]
        self._last = r
        self._trajectory.append((r.pose.x, r.pose.y))
        terminated = r.outcome in ("goal", "collision")
        truncated = r.outcome == "timeout"
        return self._observation(r), float(r.reward), terminated, truncated, self._info(r)

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        from voxshape.services.sim.render import render_map  # matplotlib only when asked

        pose = self._last.pose if self._last is not None else None
        return render_map(
            self.map,
            trajectory=self._trajectory,
            pose=pose,
            scan=self._last.laser if self._last is not None else None,
            model=self.config.model,
        )

    def close(self) -> None:
        self.sim.close()


ENV_ID = "voxshape/Navigation-v0"
# Gymnasium 1.x loads no plugins: `gym.make("module:id")` imports the module, which registers
# the id, so this form works in a fresh interpreter with no import of ours beforehand.
MAKE_ID = f"voxshape.services.sim.gym_env:{ENV_ID}"


def register() -> None:
    """Registers ENV_ID with Gymnasium unless it is there (no warning on a second call)."""
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point=NavigationEnv)


register()
