"""Visiting order of the TROIs: nearest neighbour from the start, improved by 2-opt.

The tour is open (start → … → end); 2-opt reverses segments while that shortens the path
start → T_1 → … → T_n → end measured between TROI centres.
"""

from __future__ import annotations

import math

import numpy as np

from capm_field.geometry import SE2
from capm_field.keystates import TROI


# the last tour computed: a run orders its TROIs when the mission file is checked (the walks'
# lengths) and again when it starts; 5 000 TROIs take ~2 s each time
_LAST: tuple[tuple[bytes, int], list[int]] | None = None


def order_trois(trois: list[TROI], start_xy: np.ndarray, end_xy: np.ndarray, max_rounds: int = 50) -> list[TROI]:
    global _LAST
    if len(trois) <= 1:
        return list(trois)
    key = (np.array([[t.x, t.y] for t in trois] + [list(start_xy), list(end_xy)], float).tobytes(), max_rounds)
    if _LAST is not None and _LAST[0] == key:
        return [trois[i] for i in _LAST[1]]
    idx = _tour(trois, start_xy, end_xy, max_rounds)
    _LAST = (key, [int(i) for i in idx])
    return [trois[i] for i in idx]


def _tour(trois: list[TROI], start_xy: np.ndarray, end_xy: np.ndarray, max_rounds: int) -> np.ndarray:
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
    # (the path's points and its legs' lengths are kept up to date in place as segments reverse:
    # rebuilding them for every move made 5000 TROIs take ~7 s)
    s0, e0 = np.asarray(start_xy, float), np.asarray(end_xy, float)
    idx = np.array(order)
    P = np.vstack([s0, pts[idx], e0])  # path index k ↔ idx[k - 1]
    leg = np.hypot(*np.diff(P, axis=0).T)  # leg[k] = d(P[k], P[k + 1])
    for _ in range(max_rounds):
        improved = False
        for i in range(n - 1):
            j0 = i + 1
            while j0 < n:
                a, b = P[i], P[i + 1]  # P[i-1] and P[i] in path terms (order index i is path i + 1)
                c, dd = P[j0 + 1:n + 1], P[j0 + 2:n + 2]
                delta = np.hypot(*(a - c).T) + np.hypot(*(b - dd).T) - leg[i] - leg[j0 + 1:n + 1]
                hit = np.flatnonzero(delta < -1e-12)
                if len(hit) == 0:
                    break
                j = j0 + int(hit[0])
                idx[i:j + 1] = idx[i:j + 1][::-1].copy()
                P[i + 1:j + 2] = P[i + 1:j + 2][::-1].copy()
                leg[i + 1:j + 1] = leg[i + 1:j + 1][::-1].copy()  # the reversed stretch's inner legs ...
                leg[i] = np.hypot(*(P[i + 1] - P[i]))  # ... and the two new ones at its ends
                leg[j + 1] = np.hypot(*(P[j + 2] - P[j + 1]))
                improved = True
                j0 = j + 1
        if not improved:
            break
    return idx


def x_kmax(ordered: list[TROI], i: int, end: SE2) -> SE2:
    """x_kmax of the i-th TROI (paper §IV-F): the midpoint towards the next TROI, heading there;
    the user's end pose after the last."""
    if i + 1 >= len(ordered):
        return end
    a, b = np.array(ordered[i].xy), np.array(ordered[i + 1].xy)
    m = 0.5 * (a + b)
    return SE2(float(m[0]), float(m[1]), math.atan2(b[1] - a[1], b[0] - a[0]))
