"""Geodesic distances through a plant mask, for the stage-2 estimators that measure along the
plant (`capm_field.tree_median`, `capm_field.fan_apex`): the per-pixel crossing cost (the mask,
the soil it encloses, a band round it for gaps the index left), the 8-connected grid graph for
its shortest-path distances (Dijkstra), and leaf tips as the far points of the plant seen along
it. Coordinates are (x, y) pixels of the plant's grid (see `capm_field.plant_centre`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from .compiled import kernel
from .local_peaks import disc_peaks

GAP_COST = 4.0  # geodesic cost per pixel outside the vegetation mask (bridges lost petioles)
BAND = 0.04  # gaps up to ~2·BAND·size wide may be crossed
HULL_BAND = True  # the band is cut to the plant's convex hull (tree median only): shortest paths between the
# plant's pixels seldom detour outside it at GAP_COST, and its centre is not there. Session 29: graph nodes 3 847 →
# 2 991 on average over bench seed 0's 300 frames (fan_apex's graphs, which keep the band, included); bench seeds 0–7
# 3 answers better, 2 worse by > 2 mm (grass, rosettes; wrong 42 → 42), field-photo tree-median answers 4 better
# (seedlings, a thistle), none worse; per frame −0.27 ms median, −0.42 ms mean (paired, 300 cached bench frames)
FILL_HOLES = True  # soil enclosed by the plant costs as much as the plant (`crossing_cost`). Session 23:
# field-photo bench seed 0 p90 0.278 → 0.272 S (a plantain with a bare middle 0.28 → 0.11 S), photo-like
# seed 4 p90 0.354 → 0.287 S; bench seeds 0–7: 2 answers moved (2.7 → 1.9, 0.4 → 3.7 mm)
BRIDGE_ALL = True  # parts further apart than the band are joined across the plant's hull (tree median only).
# Session 23: field-photo seed 0 p90 0.272 → 0.235 S (purslane: leaf clusters on red stalks); bench seeds 0–7:
# 25 answers moved, 14 better (20.7 → 7.6, 6.5 → 1.8 mm), 11 worse (15.8 → 24.9, 3.3 → 6.9 mm), wrong unchanged


def crossing_cost(plant: np.ndarray, size: float, bridge: bool = True) -> np.ndarray:
    """Geodesic cost per pixel for paths through a plant: 1 on the mask and in the soil it
    encloses (a rosette's middle often shows soil or pale stalks between the leaf bases: paths
    round such a hole pulled the median onto a leaf), GAP_COST in a band BAND × size round it
    (gaps across lost petioles), ∞ beyond. When the band leaves the plant in several pieces
    (leaf clusters on stalks the index misses), the band takes in the plant's convex hull, so
    that every tip is reachable from every part (else a median sees only one piece); not with
    `bridge` False (`fan_apex`, whose straightness test measures the paths along the blades).
    With `bridge`, the band outside the convex hull is dropped (HULL_BAND)."""
    m8 = plant.astype(np.uint8)
    band = cv2.dilate(m8, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5)), iterations=max(1, int(BAND * size)))
    if bridge and (BRIDGE_ALL or HULL_BAND):
        ys, xs = np.nonzero(plant)
        hull = np.zeros_like(m8)
        cv2.fillConvexPoly(hull, cv2.convexHull(np.c_[xs, ys].astype(np.int32)), 1)
        if BRIDGE_ALL and cv2.connectedComponents(band, connectivity=8)[0] > 2:
            band |= hull
        if HULL_BAND:
            band &= hull
    on = plant.copy()
    if FILL_HOLES:
        n, lab = cv2.connectedComponents(1 - m8, connectivity=4)
        if n > 2:  # soil pieces not reaching the window's border
            edge = np.unique(np.r_[lab[0], lab[-1], lab[:, 0], lab[:, -1]])
            on |= ~plant & ~np.isin(lab, edge)
    return np.where(on, 1.0, np.where(band > 0, GAP_COST, np.inf))


def geodesic_tips(g0: np.ndarray, node: np.ndarray, plant: np.ndarray, size: float) -> np.ndarray:
    """Leaf tips: local maxima of geodesic distance from the centre, one per 0.15·size window."""
    h, w = plant.shape
    valid = node >= 0
    gm = np.zeros((h, w), np.float32)
    gm[valid] = g0[node[valid]]
    gm[~np.isfinite(gm)] = 0
    gm[~plant] = 0
    r = max(2, int(0.08 * size))
    peak = disc_peaks(gm, (gm > 0.2 * gm.max()) & plant, r)
    ys, xs = np.nonzero(peak)
    if len(xs) == 0:
        return np.zeros(0, int)
    order = np.argsort(-gm[ys, xs])
    chosen: list[tuple[int, int]] = []
    for i in order:
        if all((xs[i] - x) ** 2 + (ys[i] - y) ** 2 > (1.5 * r) ** 2 for y, x in chosen):
            chosen.append((ys[i], xs[i]))
        if len(chosen) >= 14:
            break
    return np.array([node[y, x] for y, x in chosen], int)


@dataclass(frozen=True, eq=False)  # (arrays: compared by identity)
class GridGraph:
    """The 8-connected grid graph over a cost image's finite pixels (`grid_graph`): node k is
    the k-th finite pixel in row-major order; edge weight = length × mean of its two pixels' costs."""

    cost: np.ndarray  # the cost image padded by a border of ∞ (every pixel has 8 neighbours), float64
    at: np.ndarray  # node → flat position in `cost` (int64, increasing)
    index: np.ndarray  # flat position in `cost` → node, −1 where the cost is ∞ (int64)
    cmin: float  # least and largest finite cost (the bucket queue's width and span; ∞ / 0 without nodes)
    cmax: float

    @property
    def n(self) -> int:
        return len(self.at)

    def csr(self) -> sp.csr_matrix:
        """The graph as scipy's CSR matrix, both directions of every edge (for `dijkstra(...,
        directed=True)`). Nodes are numbered row-major, so a node's neighbours taken in the order
        up-left … down-right come in increasing index order (CSR's canonical form, without the
        sorting of a COO → CSR conversion)."""
        row = self.cost.shape[1]
        nbr = self.at[:, None] + _offsets(row)  # (n, 8) flat positions of the neighbours
        j = self.index.take(nbr)
        wt = _LENGTHS * 0.5 * (self.cost.ravel().take(self.at)[:, None] + self.cost.ravel().take(nbr))
        has = j >= 0
        indptr = np.zeros(self.n + 1, np.int64)
        np.cumsum(np.count_nonzero(has, axis=1), out=indptr[1:])
        return sp.csr_matrix((wt[has], j[has], indptr), shape=(self.n, self.n))


def grid_graph(cost: np.ndarray) -> tuple[GridGraph, np.ndarray]:
    """The 8-connected grid graph over the finite-cost pixels of `cost`, and the (h, w) map of
    each pixel's node (−1 where the cost is ∞)."""
    pc = np.pad(np.asarray(cost, np.float64), 1, constant_values=np.inf)
    at = np.flatnonzero(np.isfinite(pc))
    pn = np.full(pc.shape, -1, np.int64)
    pn.ravel()[at] = np.arange(len(at))
    c = pc.ravel().take(at)
    lo, hi = (float(c.min()), float(c.max())) if len(c) else (math.inf, 0.0)
    return GridGraph(pc, at, pn.ravel(), lo, hi), pn[1:-1, 1:-1]


def distances(G: GridGraph, sources: Sequence[int]) -> np.ndarray:
    """Shortest-path distances from each of the `sources` (nodes) to every node of `G`:
    (len(sources), G.n) float64, ∞ where unreachable.

    The compiled loop (`capm_field.compiled`, `_bucket_dijkstra`) walks the padded grid itself:
    no edge list, no CSR matrix, no heap. Without it, or for costs it does not take (≤ 0, or
    spread over more than BUCKET_SPREAD), scipy's Dijkstra on `G.csr()`. Both take the minimum of
    the same float64 sums d(u) + w(u, v), so the same distances to the last bit
    (tests/test_geodesic.py)."""
    src = np.asarray(sources, np.int64).reshape(-1)
    if _bucket_dijkstra is not None and G.n and 0 < G.cmin and G.cmax <= BUCKET_SPREAD * G.cmin:
        return _bucket_dijkstra(G.cost.ravel(), G.at, G.index, src, G.cost.shape[1], G.cmin, G.cmax)
    return dijkstra(G.csr(), directed=True, indices=src)


BUCKET_SPREAD = 64.0  # largest cost / smallest for the bucket queue (~1.4 × this many buckets); the
# detector's costs are 1 and GAP_COST


@kernel(lambda nb: nb.float64[:, ::1](nb.types.Array(nb.float64, 1, "C", readonly=True),
                                      nb.types.Array(nb.int64, 1, "C", readonly=True),
                                      nb.types.Array(nb.int64, 1, "C", readonly=True),
                                      nb.types.Array(nb.int64, 1, "C", readonly=True), nb.int64, nb.float64,
                                      nb.float64))
def _bucket_dijkstra(cost, at, index, src, row, cmin, cmax):  # pragma: no cover - compiled; tested against scipy
    """Dijkstra from each source over the padded grid (`GridGraph`) with a bucket queue (Dial's):
    distances cut into buckets narrower than the lightest edge (length ≥ 1 × mean cost ≥ cmin),
    so a node taken from the lowest non-empty bucket cannot be improved by any other node still
    queued, in whatever order the bucket is emptied: it is final, as in Dijkstra with a heap.
    The same labels, ~2× faster than a binary heap and than scipy on 40 plant graphs from bench
    frames (median ~3 200 nodes, 6 sources: 1.0 against 2.0 and 2.3 ms; session 45). A node
    improved again is queued again (stale entries skipped)."""
    n = at.shape[0]
    out = np.full((src.shape[0], n), np.inf)
    off = np.array([-row - 1, -row, -row + 1, -1, 1, row - 1, row, row + 1], np.int64)
    s2 = math.sqrt(2.0)
    half = np.array([s2, 1.0, s2, 1.0, 1.0, s2, 1.0, s2]) * 0.5  # (length × 0.5, as in `GridGraph.csr`)
    width = cmin * (1.0 - 1e-9)  # (the margin is far above float rounding of the distances)
    nbk = int(s2 * cmax / width) + 2  # buckets in the ring: an edge spans fewer
    head = np.empty(nbk, np.int64)
    cap = 8 * n + 1  # entries: the source, and one per improvement (≤ one per edge)
    ent = np.empty(cap, np.int64)
    nxt = np.empty(cap, np.int64)
    done = np.zeros(n, np.bool_)
    for s in range(src.shape[0]):
        dist = out[s]
        done[:] = False
        head[:] = -1
        dist[src[s]] = 0.0
        ent[0], nxt[0], head[0] = src[s], -1, 0
        used, pending, cur = 1, 1, 0
        while pending > 0:
            b = cur % nbk
            while head[b] >= 0:
                e = head[b]
                head[b] = nxt[e]
                pending -= 1
                u = ent[e]
                if done[u] or int(dist[u] / width) != cur:
                    continue  # settled already, or queued again in a lower bucket since
                done[u] = True
                d = dist[u]
                pu = at[u]
                cu = cost[pu]
                for k in range(8):
                    pv = pu + off[k]
                    v = index[pv]
                    if v < 0 or done[v]:
                        continue
                    nd = d + half[k] * (cu + cost[pv])
                    if nd < dist[v]:
                        dist[v] = nd
                        bb = int(nd / width) % nbk
                        ent[used], nxt[used], head[bb] = v, head[bb], used
                        used += 1
                        pending += 1
            cur += 1
    return out


def _offsets(row: int) -> np.ndarray:
    """Flat offsets of the 8 neighbours on a grid `row` pixels wide, up-left … down-right."""
    return np.array([-row - 1, -row, -row + 1, -1, 1, row - 1, row, row + 1])


_LENGTHS = np.array([math.sqrt(2), 1.0, math.sqrt(2), 1.0, 1.0, math.sqrt(2), 1.0, math.sqrt(2)])  # edge lengths
