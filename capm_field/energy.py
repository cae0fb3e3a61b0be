"""Energy model (paper §IV-D): c(x_i, x_j) = 1_b-move(x_i, x_j) + γ·d(x_i, x_j),
d = ‖X_b,j − X_b,i‖² + β(1 − |q_b,j · q_b,i|) as printed, or with the plain distance ‖ΔX‖
(`TaskConfig.distance_form`; Table I only comes out of the plain form, docs/bench.md).

The arm's energy is neglected (assumption a.4). A reposition x_b,k1 → x_b,k3 always counts as a
move (`force_move`): otherwise a zero-length reposition would cost 0 and c_l = c_u whenever
x_b,k1 ∈ R_m(X_w), which makes p(x_b,k1) irrelevant (PAPER_NOTES).
"""

from __future__ import annotations

import numpy as np

from .config import TaskConfig
from .geometry import SE2, yaw_quaternion_dot


def travel(dxy: np.ndarray, task: TaskConfig) -> np.ndarray:
    """Translation part of d for displacement(s) (…, 2): ‖ΔX‖² or ‖ΔX‖."""
    sq = np.einsum("...i,...i->...", dxy, dxy)
    return sq if task.distance_form == "squared" else np.sqrt(sq)


def distance(a: SE2, b: SE2, task: TaskConfig) -> float:
    """d(x_a, x_b) with the orientation term β(1 − |q_a·q_b|)."""
    t = float(travel(np.array([b.x - a.x, b.y - a.y]), task))
    return t + task.beta * (1.0 - yaw_quaternion_dot(a.yaw, b.yaw))


def cost(a: SE2, b: SE2, task: TaskConfig, force_move: bool = False) -> float:
    """c(x_a, x_b) = 1_b-move + γ·d. A move happens when d > 0 (or `force_move`)."""
    d = distance(a, b, task)
    return (1.0 if (d > 1e-12 or force_move) else 0.0) + task.gamma * d


def path_cost(poses: list[SE2], task: TaskConfig, forced: set[int] | None = None) -> float:
    """Σ c over consecutive body key states; indices in `forced` count as a move even if zero-length."""
    forced = forced or set()
    return sum(cost(poses[i], poses[i + 1], task, force_move=(i + 1) in forced) for i in range(len(poses) - 1))
