"""Visiting order of the TROIs: nearest neighbour from the start, improved by 2-opt.

The tour is open (start → … → end); 2-opt reverses segments while that shortens the path
start → T_1 → … → T_n → end measured between TROI centres.
"""

from __future__ import annotations

import math

import numpy as np

from capm_field.geometry import SE2
from capm_field.keystates import TROI


def _length(pts: np.ndarray, order: list[int], start: np.ndarray, end: np.ndarray) -> float:
    path = np.vstack([start, pts[order], end])
    return float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)))


def order_trois(trois: list[TROI], start_xy: np.ndarray, end_xy: np.ndarray, max_rounds: int = 50) -> list[TROI]:
    if len(trois) <= 1:
        return list(trois)
    pts = np.array([t.xy for t in trois])
    left = set(range(len(trois)))
    order: list[int] = []
    cur = np.asarray(start_xy, float)
    while left:
        nxt = min(left, key=lambda i: (float(np.linalg.norm(pts[i] - cur)), i))
        order.append(nxt)
        left.remove(nxt)
        cur = pts[nxt]
    best = _length(pts, order, start_xy, end_xy)
    for _ in range(max_rounds):
        improved = False
        for i in range(len(order) - 1):
            for j in range(i + 1, len(order)):
                cand = order[:i] + order[i : j + 1][::-1] + order[j + 1 :]
                L = _length(pts, cand, start_xy, end_xy)
                if L < best - 1e-12:
                    order, best, improved = cand, L, True
        if not improved:
            break
    return [trois[i] for i in order]


def x_kmax(ordered: list[TROI], i: int, end: SE2) -> SE2:
    """x_kmax of the i-th TROI (paper §IV-F): the midpoint towards the next TROI, heading there;
    the user's end pose after the last."""
    if i + 1 >= len(ordered):
        return end
    a, b = np.array(ordered[i].xy), np.array(ordered[i + 1].xy)
    m = 0.5 * (a + b)
    return SE2(float(m[0]), float(m[1]), math.atan2(b[1] - a[1], b[0] - a[0]))
