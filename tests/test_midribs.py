"""Stage 2's midrib estimator (`midribs.midrib_centre`, `centre_cascade.MIDRIBS`): where the
lines inside a broad-leaved plant converge, and no answer from one leaf's own veins."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from capm_field import centre_cascade, midribs
from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig, TaskConfig
from capm_field.detector import detect_centre, ground_centre, roi_from_troi
from sim_bench.perception_bench import make_case

CAM = PinholeCamera.from_config(CameraConfig())
CROWN = (92, 112)


def _soil(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(110 + cv2.GaussianBlur(rng.normal(0, 12, (220, 220)).astype(np.float32), (0, 0), 1.2), 0, 255)


def _rosette(ribs: bool, turn: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Five dark leaves of uneven length from CROWN (their mask's middle lies off the crown), each
    with a pale midrib from the crown to its tip when `ribs`."""
    grey, mask = _soil(), np.zeros((220, 220), np.uint8)
    for a, length in zip(np.radians([10, 80, 150, 215, 290]) + turn, (95, 60, 85, 45, 70)):
        u = np.array([math.cos(a), math.sin(a)])
        mid = np.array(CROWN) + u * length / 2
        cv2.ellipse(mask, (int(mid[0]), int(mid[1])), (int(length / 2), int(length / 6)), math.degrees(a), 0, 360, 1, -1)
    grey[mask > 0] = 60
    if ribs:
        for a, length in zip(np.radians([10, 80, 150, 215, 290]) + turn, (95, 60, 85, 45, 70)):
            tip = np.array(CROWN) + np.array([math.cos(a), math.sin(a)]) * 0.9 * length
            cv2.line(grey, CROWN, (int(tip[0]), int(tip[1])), 170, 2)
    return grey.astype(np.uint8), mask > 0


@pytest.mark.parametrize("turn", [0.0, 0.4, 1.3])
def test_midribs_meet_at_the_crown_where_the_mask_middle_does_not(turn: float) -> None:
    grey, mask = _rosette(True, turn)
    got = midribs.midrib_centre(grey, mask)
    assert got is not None
    assert math.dist(got[0], CROWN) < 3.0 and got[1] >= midribs.MIN_DIRS
    ys, xs = np.nonzero(mask)
    assert math.dist((xs.mean(), ys.mean()), CROWN) > 8.0  # what the fallbacks start from


def _three_leaves(stray: bool) -> tuple[np.ndarray, np.ndarray]:
    """Three dark leaves from CROWN with pale midribs (three directions); `stray`: two long veins
    along the first leaf that do not pass the crown (lines that do not agree)."""
    grey, mask = _soil(2), np.zeros((220, 220), np.uint8)
    leaves = list(zip(np.radians([20, 140, 260]), (95, 70, 85)))
    for a, length in leaves:
        mid = np.array(CROWN) + np.array([math.cos(a), math.sin(a)]) * length / 2
        cv2.ellipse(mask, (int(mid[0]), int(mid[1])), (int(length / 2), int(length / 5)), math.degrees(a), 0, 360, 1, -1)
    grey[mask > 0] = 60
    for a, length in leaves:
        tip = np.array(CROWN) + np.array([math.cos(a), math.sin(a)]) * 0.9 * length
        cv2.line(grey, CROWN, (int(tip[0]), int(tip[1])), 170, 2)
    if stray:  # (parallel to the first leaf's midrib, 9 px to each side of it)
        a = leaves[0][0]
        u, n = np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])
        for side in (-9, 9):
            p0, p1 = np.array(CROWN) + 30 * u + side * n, np.array(CROWN) + 78 * u + side * n
            cv2.line(grey, (int(p0[0]), int(p0[1])), (int(p1[0]), int(p1[1])), 170, 2)
    return grey.astype(np.uint8), mask > 0


def test_three_midribs_answer_only_when_they_are_nearly_all_the_lines(monkeypatch) -> None:
    grey, mask = _three_leaves(stray=False)
    got = midribs.midrib_centre(grey, mask)
    assert got is not None and math.dist(got[0], CROWN) < 3.0 and got[1] == 3 and got[2] >= midribs.FEW_DIRS_SHARE
    monkeypatch.setattr(midribs, "FEW_DIRS_SHARE", 1.01)  # four directions needed: no answer
    assert midribs.midrib_centre(grey, mask) is None
    monkeypatch.undo()
    grey, mask = _three_leaves(stray=True)
    assert midribs.midrib_centre(grey, mask) is None

def test_no_lines_inside_the_leaves_no_answer() -> None:
    grey, mask = _rosette(False)
    assert midribs.midrib_centre(grey, mask) is None


def _mallow() -> tuple[np.ndarray, np.ndarray, list]:
    """Three round leaves; the first a star of short veins round its middle (palmate veins), the
    others' veins unseen."""
    grey, mask = _soil(1), np.zeros((220, 220), np.uint8)
    centres = [(70, 80), (150, 85), (110, 155)]
    for c in centres:
        cv2.circle(mask, c, 34, 1, -1)
    grey[mask > 0] = 60
    for c in centres[:1]:
        for a in np.radians(np.arange(0, 360, 40) + 7):
            cv2.line(grey, c, (int(c[0] + 28 * math.cos(a)), int(c[1] + 28 * math.sin(a))), 170, 2)
    return grey.astype(np.uint8), mask > 0, centres


def test_one_leafs_own_veins_are_not_the_crown(monkeypatch) -> None:
    grey, mask, centres = _mallow()
    assert midribs.midrib_centre(grey, mask) is None
    monkeypatch.setattr(midribs, "MIN_REACH", 0.0)  # without the reach test: a leaf's middle
    got = midribs.midrib_centre(grey, mask)
    assert got is not None and math.dist(got[0], centres[0]) < 4.0


def test_tiny_empty_or_lineless_inputs_give_none() -> None:
    assert midribs.midrib_centre(np.zeros((10, 10), np.uint8), np.zeros((10, 10), bool)) is None
    flat = np.full((120, 120), 90, np.uint8)
    assert midribs.midrib_centre(flat, np.ones((120, 120), bool)) is None


def test_a_photo_sized_window_is_shrunk_and_answers_in_its_pixels() -> None:
    grey, mask = _rosette(True)
    big = cv2.resize(grey, None, fx=3, fy=3, interpolation=cv2.INTER_CUBIC)
    bigm = cv2.resize(mask.astype(np.uint8), None, fx=3, fy=3, interpolation=cv2.INTER_NEAREST) > 0
    got = midribs.midrib_centre(big, bigm)
    assert got is not None and math.dist(got[0], (3 * CROWN[0] + 1, 3 * CROWN[1] + 1)) < 9.0


def test_a_bench_rosette_found_by_its_midribs(monkeypatch) -> None:
    """Bench seed 11 case 88: a rosette whose geometric median lay 47.6 mm off the crown."""
    case = make_case(11, 88, CAM, TaskConfig().delta, False)
    img = case.scene.render(case.T, CAM)
    roi = roi_from_troi(CAM, case.T, case.troi_centre, case.troi_radius)

    def error_mm() -> float:
        dbg: dict = {}
        det = detect_centre(img, roi, debug=dbg)
        assert det.reason is None
        return 1000 * float(np.linalg.norm(ground_centre(CAM, case.T, det) - case.scene.weeds[0].centre))

    assert case.kind == "rosette" and error_mm() < 5.0
    monkeypatch.setattr(centre_cascade, "MIDRIBS", False)
    assert error_mm() > 30.0


def test_a_float_window_and_threads_give_the_same_answer() -> None:
    from concurrent.futures import ThreadPoolExecutor

    grey, mask = _rosette(True)
    want = midribs.midrib_centre(grey, mask)
    assert want is not None
    same = midribs.midrib_centre(grey.astype(np.float32), mask)
    assert same is not None and np.allclose(same[0], want[0])
    with ThreadPoolExecutor(4) as ex:
        got = list(ex.map(lambda _: midribs.midrib_centre(grey, mask), range(8)))
    assert all(g is not None and np.allclose(g[0], want[0]) for g in got)
