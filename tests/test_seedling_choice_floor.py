"""bench/seedling_choice_floor.py: the stage-1 score of a scene's true plants (area × centrality)."""

import importlib.util
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from sim_bench.plants import Part, Plant, make_plant

_spec = importlib.util.spec_from_file_location(
    "seedling_choice_floor", Path(__file__).resolve().parents[1] / "bench" / "seedling_choice_floor.py")
floor = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(floor)


def _case(weed_at, others):
    """A case whose TROI is the unit-radius disc × 0.25 m at the origin; seedlings of one shape."""
    r = 0.25

    def seedling(at, size):
        return make_plant("seedling", np.random.default_rng(7), np.asarray(at, float) * r, size)

    weed = seedling(weed_at, 0.02)
    plants = [weed] + [seedling(at, size) for at, size in others]
    return SimpleNamespace(troi_centre=np.zeros(2), troi_radius=r,
                           scene=SimpleNamespace(weeds=[SimpleNamespace(plant=weed)], plants=plants))


def test_leaf_area_of_a_square_leaf():
    sq = np.array([[0, 0], [0.01, 0], [0.01, 0.01], [0, 0.01]], float)
    p = Plant("seedling", np.zeros(2), (Part(sq, np.zeros(2), sq[2], np.array([0.2, 0.5, 0.2])),), 0.015)
    assert floor.leaf_area(p) == pytest.approx(1e-4, rel=0.03)


def test_an_equal_distractor_as_far_out_ties_and_a_nearer_one_wins():
    ratio, n = floor.frame_ratio(_case((0.5, 0.0), [((-0.5, 0.0), 0.02)]))
    assert n == 1 and ratio == pytest.approx(1.0, rel=0.03)
    ratio, _ = floor.frame_ratio(_case((0.5, 0.0), [((0.0, -0.1), 0.02)]))
    expect = math.exp(-0.5 * (0.1 / floor.CENTRAL_SIGMA) ** 2) / math.exp(-0.5 * (0.5 / floor.CENTRAL_SIGMA) ** 2)
    assert ratio == pytest.approx(expect, rel=0.03) and ratio > 1


def test_a_smaller_distractor_loses_and_one_outside_the_troi_is_not_counted():
    ratio, n = floor.frame_ratio(_case((0.3, 0.0), [((-0.3, 0.0), 0.01)]))
    assert n == 1 and ratio == pytest.approx(0.25, rel=0.1)  # half the size: a quarter of the area
    ratio, n = floor.frame_ratio(_case((0.3, 0.0), [((1.2, 0.0), 0.04)]))
    assert n == 0 and ratio == 0.0
