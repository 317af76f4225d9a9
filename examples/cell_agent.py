"""A small learner through TRUAV's agent API (agents/api.py): one Q-table per UAV over the cell of a
coarse grid it is in and whether it has vehicles in range, epsilon-greedy over the 16 moves and hover.
The tutorial docs/tutorials/own-agent.md trains it, flies it as a swarm, under faults, and re-simulates it:

    PYTHONPATH=examples truav train --agent cell_agent:CellAgent --out runs/cell-agent
"""
import numpy as np

from agents.api import HOVER, N_ACTIONS, UavAgent

CELLS = 5           # the area as a CELLS x CELLS grid
MOVES = N_ACTIONS + 1  # column N_ACTIONS is HOVER


class CellAgent(UavAgent):
    alpha, gamma, epsilon = 0.1, 0.9, 0.1

    def __init__(self, cfg, uav, rng):
        super().__init__(cfg, uav, rng)            # keeps cfg, uav, rng; self.training
        self.cell_m = cfg.scenario.area_m / CELLS  # cfg: the run's config (docs/reference/agent-api.md#cfg)
        self.q = np.zeros((CELLS * CELLS * 2, MOVES))
        self.state, self.move = 0, 0

    def observe(self, view):
        """The state: the grid cell of the UAV's position, and whether any vehicle is in its range."""
        col, row = (min(int(c // self.cell_m), CELLS - 1) for c in view.pos)
        return (row * CELLS + col) * 2 + (view.vehicles_in_range > 0)

    def act(self, view):
        self.state = self.observe(view)
        if self.training and self.rng.random() < self.epsilon:  # every random number from self.rng
            self.move = int(self.rng.integers(MOVES))
        else:
            self.move = int(np.argmax(self.q[self.state]))
        return HOVER if self.move == N_ACTIONS else self.move

    def learn(self, view, reward, done):
        if not self.training:  # a greedy evaluation: learn nothing
            return
        target = reward if done else reward + self.gamma * self.q[self.observe(view)].max()
        self.q[self.state, self.move] += self.alpha * (target - self.q[self.state, self.move])

    def state_dict(self):
        return {"q": self.q.copy()}  # named arrays of numbers: saved after training, loaded to fly

    def load_state_dict(self, state):
        if state["q"].shape != self.q.shape:
            raise ValueError(f"q must be shaped {self.q.shape}, got {state['q'].shape}")
        self.q = np.array(state["q"], np.float64)
