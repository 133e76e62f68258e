"""A tiny custom env for trl_cartpole: walk right along a corridor to its far end.

Train it with no code change (``examples/`` on PYTHONPATH, the id names module:class):

    PYTHONPATH=examples python scripts/train.py env.id=corridor:Corridor eval.solve_threshold=1
"""

import gymnasium as gym
import numpy as np


class Corridor(gym.Env):
    """``length`` cells; the agent starts in cell 0 and gets +1 on reaching the last one.

    Observation: the one-hot cell index (a vector of ``length`` floats). Actions: 0 = left,
    1 = right (a wall stops the agent at cell 0). The episode is cut off after ``max_steps``.
    """

    def __init__(self, length: int = 8, max_steps: int = 50):
        self.length, self.max_steps = length, max_steps
        self.observation_space = gym.spaces.Box(0.0, 1.0, (length,), np.float32)
        self.action_space = gym.spaces.Discrete(2)

    def _observation(self) -> np.ndarray:
        one_hot = np.zeros(self.length, np.float32)
        one_hot[self.position] = 1.0
        return one_hot

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.position, self.steps = 0, 0
        return self._observation(), {}

    def step(self, action):
        self.position = max(0, self.position + (1 if action == 1 else -1))
        self.steps += 1
        terminated = self.position == self.length - 1
        truncated = self.steps >= self.max_steps and not terminated
        return self._observation(), float(terminated), terminated, truncated, {}
