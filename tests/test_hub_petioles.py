"""`hub_petioles`: a clover's centre where the petioles leaving its trefoil hubs meet, confirmed in
the image (docs/perception.md §2, stage 2)."""

from __future__ import annotations

import math

import cv2
import numpy as np

from capm_field import compound_leaf, hub_petioles, plant_centre
from capm_field.vegetation import vegetation_index


def _clover(centre=(150.0, 170.0), angles=(-100, -60, -20), petiole_len=70.0, petioles=True, seed=0) -> np.ndarray:
    """Three trefoils all to one side of the centre (outside their hull), on noisy brown soil."""
    rng = np.random.default_rng(seed)
    img = np.empty((300, 320, 3), np.float32)
    img[:] = (70, 95, 120)
    img += cv2.GaussianBlur(rng.normal(0, 10, img.shape).astype(np.float32), (0, 0), 1.2)
    c = np.array(centre)
    for a in np.radians(angles):
        end = c + petiole_len * np.array([math.cos(a), math.sin(a)])
        if petioles:
            cv2.line(img, tuple(np.round(c * 16).astype(int)), tuple(np.round(end * 16).astype(int)), (45, 80, 85), 2,
                     cv2.LINE_AA, shift=4)
        for da in (-2.0, 0.0, 2.0):
            m = end + 11 * np.array([math.cos(a + da), math.sin(a + da)])
            cv2.ellipse(img, tuple(np.round(m).astype(int)), (11, 8), math.degrees(a + da), 0, 360, (50, 140, 60), -1,
                        cv2.LINE_AA)
    return np.clip(img, 0, 255).astype(np.uint8)


def _centre(img: np.ndarray):
    vi = vegetation_index(img)
    soil = float(np.median(vi))
    plant = vi > soil + 0.05
    ys, xs = np.nonzero(plant)
    size = math.hypot(np.ptp(xs) + 1, np.ptp(ys) + 1)
    hubs = compound_leaf.compound_hubs(plant, vi, soil, size)
    return hub_petioles.hub_petiole_centre(img, 0, 0, 1.0, 1.0, plant, plant_centre.broad_parts(plant)[1], hubs)


def test_petioles_meeting_outside_the_leaves_give_the_centre() -> None:
    for seed, angles in ((0, (-100, -60, -20)), (1, (10, 60, 100)), (2, (-150, -110, -60))):
        uv = _centre(_clover(angles=angles, seed=seed))
        assert uv is not None and float(np.hypot(uv[0] - 150, uv[1] - 170)) < 4.0, (seed, uv)


def test_no_petioles_seen_no_answer() -> None:
    """Trefoils alone: their rays are not confirmed, so the estimator declines (the medians answer)."""
    for seed in range(3):
        assert _centre(_clover(petioles=False, seed=seed)) is None
