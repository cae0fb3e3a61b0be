"""`geodesic.distances`: the compiled grid Dijkstra gives scipy's distances on the graph's CSR
matrix to the last bit (the tree median and the fan apex read them), and the fallback without the
compiled loop is scipy's."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse.csgraph import dijkstra

from capm_field import geodesic
from capm_field.geodesic import GAP_COST, distances, grid_graph


def _cost(seed: int, h: int, w: int, share: float, holes: float, smooth: bool) -> np.ndarray:
    rng = np.random.default_rng(seed)
    # the detector's costs (1 on the plant, GAP_COST in the band, ∞ beyond) or arbitrary positive ones
    cost = np.where(rng.random((h, w)) < share, 1.0, GAP_COST) if not smooth else rng.uniform(0.1, 5.0, (h, w))
    cost[rng.random((h, w)) < holes] = np.inf
    return cost


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 60), w=st.integers(1, 60), share=st.floats(0.0, 1.0),
       holes=st.floats(0.0, 0.5), smooth=st.booleans(), k=st.integers(1, 6))
def test_compiled_distances_equal_scipy_dijkstra(seed, h, w, share, holes, smooth, k) -> None:
    cost = _cost(seed, h, w, share, holes, smooth)
    G, node = grid_graph(cost)
    if G.n == 0:
        return
    src = np.random.default_rng(seed + 1).integers(0, G.n, k)
    got = distances(G, src.tolist())
    want = dijkstra(G.csr(), directed=True, indices=src)
    assert got.shape == (k, G.n)
    assert np.array_equal(got, want)  # the same float64 sums, ∞ where a part is cut off
    assert (got[np.arange(k), src] == 0).all()


def test_a_plant_in_two_pieces_is_unreachable_across_the_gap() -> None:
    cost = np.full((5, 9), 1.0)
    cost[:, 4] = np.inf
    G, node = grid_graph(cost)
    d = distances(G, [node[2, 0]])[0]
    assert np.isinf(d[node[:, 5:][np.isfinite(cost[:, 5:])]]).all()
    assert d[node[2, 3]] == pytest.approx(3.0) and d[node[0, 2]] == pytest.approx(2 * np.sqrt(2))  # straight, diagonal
    assert d[node[0, 3]] == pytest.approx(2 * np.sqrt(2) + 1.0)


def test_without_the_compiled_loop_scipy_answers_the_same(monkeypatch) -> None:
    cost = _cost(7, 40, 50, 0.6, 0.1, False)
    G, node = grid_graph(cost)
    src = [0, G.n // 2, G.n - 1]
    compiled = distances(G, src)
    monkeypatch.setattr(geodesic, "_bucket_dijkstra", None)
    assert np.array_equal(distances(G, src), compiled)


def test_costs_spread_wider_than_the_buckets_take_are_scipy_s() -> None:
    cost = _cost(3, 30, 30, 0.5, 0.1, True)
    cost[0, 0] = 1000.0 * np.nanmin(cost[np.isfinite(cost)])
    G, node = grid_graph(cost)
    assert np.array_equal(distances(G, [1, 5]), dijkstra(G.csr(), directed=True, indices=[1, 5]))


def test_the_loop_is_compiled_here() -> None:
    assert geodesic._bucket_dijkstra is not None
