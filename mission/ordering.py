"""Visiting order of the TROIs: nearest neighbour from the start, improved by 2-opt.

The tour is open (start → … → end); 2-opt reverses segments while that shortens the path
start → T_1 → … → T_n → end measured between TROI centres.
"""

from __future__ import annotations

import math

import numpy as np

from capm_field.geometry import SE2
from capm_field.keystates import TROI


def order_trois(trois: list[TROI], start_xy: np.ndarray, end_xy: np.ndarray, max_rounds: int = 50) -> list[TROI]:
    if len(trois) <= 1:
        return list(trois)
    pts = np.array([t.xy for t in trois], float)
    n = len(trois)
    # nearest neighbour from the start (ties: the lower index)
    left = np.ones(n, bool)
    order: list[int] = []
    cur = np.asarray(start_xy, float)
    for _ in range(n):
        d = np.where(left, np.hypot(*(pts - cur).T), np.inf)
        nxt = int(np.argmin(d))
        order.append(nxt)
        left[nxt] = False
        cur = pts[nxt]
    # 2-opt, first improvement in (i, j) scan order: reversing order[i..j] changes the path
    # length by d(P[i-1], P[j]) + d(P[i], P[j+1]) − d(P[i-1], P[i]) − d(P[j], P[j+1]) on the path
    # P = start, order…, end — evaluated for every j at once (O(n²) per round, not O(n³))
    s0, e0 = np.asarray(start_xy, float), np.asarray(end_xy, float)
    for _ in range(max_rounds):
        improved = False
        for i in range(n - 1):
            j0 = i + 1
            while j0 < n:
                P = np.vstack([s0, pts[order], e0])  # path index k ↔ order[k - 1]
                a, b = P[i], P[i + 1]  # P[i-1] and P[i] in path terms (order index i is path i + 1)
                js = np.arange(j0, n)
                c, dd = P[js + 1], P[js + 2]
                delta = np.hypot(*(a - c).T) + np.hypot(*(b - dd).T) - np.hypot(*(a - b)) - np.hypot(*(c - dd).T)
                hit = np.flatnonzero(delta < -1e-12)
                if len(hit) == 0:
                    break
                j = int(js[hit[0]])
                order = order[:i] + order[i : j + 1][::-1] + order[j + 1 :]
                improved = True
                j0 = j + 1
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
