"""Visiting order of targets on a field: nearest neighbour from the start, then 2-opt.

The same method as `mission/ordering.py` (which `capm_field` may not import): an open tour
start → T_1 → … → T_n → end between target points. The 2-opt step is vectorised — all segment
reversals are scored at once from the distance matrix — so re-ordering 50 targets after an
observation takes a millisecond, not the O(n³) of re-measuring every candidate path.
"""

from __future__ import annotations

import numpy as np


def tour_length(pts: np.ndarray, order: list[int], start: np.ndarray, end: np.ndarray | None) -> float:
    path = [np.asarray(start, float)[None], pts[order]]
    if end is not None:
        path.append(np.asarray(end, float)[None])
    p = np.vstack(path)
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))


def order_points(pts: np.ndarray, start: np.ndarray, end: np.ndarray | None, max_rounds: int = 200) -> list[int]:
    """Indices of `pts` (n, 2) in visiting order: NN from `start`, improved by 2-opt (open tour to `end`)."""
    pts = np.asarray(pts, float)
    n = len(pts)
    if n <= 1:
        return list(range(n))
    left = np.ones(n, bool)
    order: list[int] = []
    cur = np.asarray(start, float)
    for _ in range(n):
        d = np.where(left, np.linalg.norm(pts - cur, axis=1), np.inf)
        k = int(np.argmin(d))  # ties: lowest index (deterministic)
        order.append(k)
        left[k] = False
        cur = pts[k]
    # Nodes: 0 = start, 1..n = targets in tour order, n+1 = end (absent end: a free end, zero cost).
    for _ in range(max_rounds):
        nodes = np.vstack([np.asarray(start, float)[None], pts[order], (np.asarray(end, float) if end is not None else pts[order[-1]])[None]])
        D = np.linalg.norm(nodes[:, None] - nodes[None], axis=2)
        if end is None:
            D[:, -1] = 0.0  # free end: the last edge costs nothing
            D[-1, :] = 0.0
        m = n + 2
        i = np.arange(0, m - 2)[:, None]  # edge (i, i+1)
        j = np.arange(1, m - 1)[None, :]  # edge (j, j+1), reversing nodes i+1..j
        valid = j > i
        ii, jj = np.broadcast_arrays(i, j)
        delta = D[ii, jj] + D[ii + 1, jj + 1] - D[ii, ii + 1] - D[jj, jj + 1]
        delta = np.where(valid, delta, np.inf)
        k = int(np.argmin(delta))
        if delta.flat[k] >= -1e-12:
            break
        a, b = int(ii.flat[k]), int(jj.flat[k])  # reverse tour positions a..b-1 (nodes a+1..b)
        order[a:b] = order[a:b][::-1]
    return order
