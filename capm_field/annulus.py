"""Vectorised geometry of annular regions for the planners.

All body-placement regions are unions of annuli around a ground point (RadialSet): R_o around
X_w, R_m around X_w or X̄_w. The planners need two primitives, evaluated for many candidate
points at once:
  * `via_cost`: min over P3 in the annulus of γD(P1, P3) + c(P3, E) — the best reposition on
    the way to E (c_l without its move indicators);
  * `best_stop`: the best single stop P in the annulus between S and E (planner a).
For the plain distance the optimum is on the segment when it meets the annulus, else on a
boundary circle (found by a vectorised angle search + local refinement); for the squared
distance it is the projection of the midpoint onto the annulus.
"""

from __future__ import annotations

import math

import numpy as np

from .config import TaskConfig
from .reachability import RadialSet

_N_ANGLES = 24


def seg_point_dist(P: np.ndarray, Q: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) distance from X to segments P→Q (…, 2)."""
    d = Q - P
    n2 = np.einsum("...i,...i->...", d, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.clip(np.where(n2 > 0, np.einsum("...i,...i->...", X - P, d) / n2, 0.0), 0.0, 1.0)
    closest = P + s[..., None] * d
    dmin = np.linalg.norm(closest - X, axis=-1)
    dmax = np.maximum(np.linalg.norm(P - X, axis=-1), np.linalg.norm(Q - X, axis=-1))
    return dmin, dmax


def _first_entry(P: np.ndarray, Q: np.ndarray, X: np.ndarray, a: float, b: float) -> np.ndarray:
    """First point along P→Q inside the annulus [a, b] around X (assumes the segment meets it)."""
    d = Q - P
    f = P - X
    A = np.einsum("...i,...i->...", d, d)
    B = 2 * np.einsum("...i,...i->...", f, d)
    rp = np.linalg.norm(f, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        # Outside the outer circle: smallest root of |f + s·d| = b.
        C = np.einsum("...i,...i->...", f, f) - b * b
        disc = np.maximum(B * B - 4 * A * C, 0.0)
        s_out = np.clip((-B - np.sqrt(disc)) / (2 * A), 0.0, 1.0)
        # Inside the inner circle: larger root of |f + s·d| = a.
        C2 = np.einsum("...i,...i->...", f, f) - a * a
        disc2 = np.maximum(B * B - 4 * A * C2, 0.0)
        s_in = np.clip((-B + np.sqrt(disc2)) / (2 * A), 0.0, 1.0)
    s = np.where(rp > b, s_out, np.where(rp < a, s_in, 0.0))
    s = np.where(A > 0, s, 0.0)
    return P + s[..., None] * d


def _circle_search(P: np.ndarray, E: np.ndarray, X: np.ndarray, radius: float, task: TaskConfig) -> tuple[np.ndarray, np.ndarray]:
    """min over points C on the circle (X, radius) of D(P, C) + D(C, E); returns (value, C).
    P: (n, 2); X: (2,) or (n, 2) (one circle centre per row)."""
    X = np.broadcast_to(np.asarray(X, dtype=float), P.shape)
    th = np.linspace(-math.pi, math.pi, _N_ANGLES, endpoint=False)
    ring = X[:, None, :] + radius * np.stack([np.cos(th), np.sin(th)], 1)[None]  # (n, m, 2)
    v = _trav(P[:, None, :] - ring, task) + _trav(ring - E, task)
    i = np.argmin(v, axis=1)
    best_th = th[i]
    step = 2 * math.pi / _N_ANGLES
    for _ in range(4):  # local refinement around the best angle
        loc = best_th[:, None] + np.linspace(-step, step, 7)[None]
        C = X[:, None, :] + radius * np.stack([np.cos(loc), np.sin(loc)], -1)
        v = _trav(P[:, None, :] - C, task) + _trav(C - E, task)
        j = np.argmin(v, axis=1)
        best_th = loc[np.arange(len(P)), j]
        step /= 3
    C = X + radius * np.stack([np.cos(best_th), np.sin(best_th)], -1)
    return _trav(P - C, task) + _trav(C - E, task), C


def _trav(d: np.ndarray, task: TaskConfig) -> np.ndarray:
    sq = np.einsum("...i,...i->...", d, d)
    return sq if task.distance_form == "squared" else np.sqrt(sq)


def via_cost(P: np.ndarray, E: np.ndarray, X: np.ndarray, rset: RadialSet, task: TaskConfig) -> tuple[np.ndarray, np.ndarray]:
    """Lower-branch cost c_l = c(P, P3) + c(P3, E) minimised over P3 ∈ annulus(X, rset), for each P (n, 2).

    X is the annulus centre, (2,) or one per row (n, 2). The reposition P → P3 always counts as
    a move; P3 → E counts unless P3 = E. Returns (c_l (n,), P3 (n, 2)).
    """
    P = np.atleast_2d(np.asarray(P, dtype=float))
    E = np.asarray(E, dtype=float)
    X = np.broadcast_to(np.asarray(X, dtype=float), P.shape)
    g = task.gamma
    best_p3 = np.tile(E, (len(P), 1))
    # Stop at E itself when E is in the annulus: P → E then flame, no last move.
    best = np.where(rset.contains(np.linalg.norm(E - X, axis=1)), 1.0 + g * _trav(E - P, task), np.inf)
    for a, b in rset.intervals:
        if task.distance_form == "squared":
            M = 0.5 * (P + E)
            v = M - X
            r = np.linalg.norm(v, axis=1)
            with np.errstate(divide="ignore", invalid="ignore"):
                u = np.where(r[:, None] > 1e-12, v / r[:, None], np.array([1.0, 0.0]))
            P3 = X + np.clip(r, a, b)[:, None] * u
            val = 2.0 + g * (_trav(P3 - P, task) + _trav(E - P3, task))
        else:
            dmin, dmax = seg_point_dist(P, np.broadcast_to(E, P.shape), X)
            hits = (dmin <= b) & (dmax >= a)
            val = np.full(len(P), np.inf)
            P3 = np.zeros_like(P)
            if hits.any():
                P3[hits] = _first_entry(P[hits], np.broadcast_to(E, P[hits].shape), X[hits], a, b)
                val[hits] = 2.0 + g * np.linalg.norm(E - P[hits], axis=1)
            miss = ~hits
            if miss.any():
                # Segment entirely inside the inner disc → inner circle, else → outer circle.
                inner = dmax[miss] < a
                for radius, sel in ((a, inner), (b, ~inner)):
                    if sel.any() and radius > 0:
                        idx = np.flatnonzero(miss)[sel]
                        v, C = _circle_search(P[idx], E, X[idx], radius, task)
                        val[idx] = 2.0 + g * v
                        P3[idx] = C
        better = val < best
        best = np.where(better, val, best)
        best_p3[better] = P3[better]
    return best, best_p3


def best_stop(S: np.ndarray, E: np.ndarray, X: np.ndarray, rset: RadialSet, task: TaskConfig, tiebreak: str, rng: np.random.Generator) -> np.ndarray:
    """Planner (a): the stop P ∈ annulus(X, rset) minimising c(S, P) + c(P, E).

    With the plain distance every point of the segment S→E inside the annulus is optimal; the
    paper does not say which is taken. `tiebreak`: 'first' (first along the path), 'uniform'
    (uniform over the tied stretch), 'nearest' (the tied point nearest X_w).
    """
    S = np.asarray(S, float)
    E = np.asarray(E, float)
    X = np.asarray(X, float)
    if task.distance_form == "squared":
        _, P3 = via_cost(S[None], E, X, rset, task)
        return P3[0]
    # Sample the segment finely; points inside the annulus are the tied stretch.
    s = np.linspace(0.0, 1.0, 2001)
    pts = S + s[:, None] * (E - S)
    inside = rset.contains(np.linalg.norm(pts - X, axis=1))
    if inside.any():
        idx = np.flatnonzero(inside)
        if tiebreak == "first":
            return pts[idx[0]]
        if tiebreak == "nearest":
            return pts[idx[np.argmin(np.linalg.norm(pts[idx] - X, axis=1))]]
        return pts[rng.choice(idx)]
    best, bestC = np.inf, E
    for a, b in rset.intervals:
        for radius in (a, b):
            if radius > 0:
                v, C = _circle_search(S[None], E, X, radius, task)
                if v[0] < best:
                    best, bestC = float(v[0]), C[0]
    return bestC
