"""Cast shadows: the lit and shadowed parts of a window (`capm_field.shadow_regions`), and the
detector's look into each part (`detector._in_shadow_parts`) when the whole window found no plant
or chose another plant than the one the part look finds."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

import capm_field.candidates as candidates
import capm_field.detector as detector
from capm_field.detector import detect_centre
from capm_field.shadow_regions import _cell_medians, shadow_regions
from field_photos import crown_off, field_photos


def _soil(rng: np.random.Generator, shape=(240, 320), bgr=(80, 110, 150)) -> np.ndarray:
    """Brown soil with clods of a few pixels (mottled well below a cell of the region map)."""
    tex = cv2.GaussianBlur(rng.normal(0, 1, shape).astype(np.float32), (0, 0), 2.0)
    tex = 1.0 + 0.12 * tex / tex.std()
    return np.clip(np.asarray(bgr, np.float32) * tex[..., None], 0, 255)


def _shade(img: np.ndarray, share: float, angle: float, soft: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """Shade the part of the frame beyond a straight edge (its `share` of the frame, roughly):
    darker and bluer, as under sky light only. Returns (image, true shadow mask)."""
    h, w = img.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    d = (xx - w / 2) * math.cos(angle) + (yy - h / 2) * math.sin(angle)
    edge = np.quantile(d, 1 - share)
    s = 1 / (1 + np.exp(-(d - edge) / soft))
    gain = np.array([0.55, 0.42, 0.35], np.float32)  # B, G, R under sky light
    out = img * (1 - s[..., None] * (1 - gain))
    return np.clip(out, 0, 255).astype(np.uint8), d > edge


@pytest.mark.parametrize("share, angle", [(0.3, 0.3), (0.5, 2.0), (0.7, 4.0)])
def test_a_cast_shadow_splits_the_window_along_its_edge(share: float, angle: float) -> None:
    rng = np.random.default_rng(int(share * 10))
    img, truth = _shade(_soil(rng), share, angle)
    inside = np.ones(truth.shape, bool)
    parts = shadow_regions(img, inside)
    assert len(parts) == 2
    (lit, lit_core), (shadow, shadow_core) = parts
    assert not np.any(lit & shadow) and np.all(lit | shadow)
    assert np.mean(shadow == truth) > 0.95
    # the cores keep out of the penumbra (4 px soft): none reaches 3 px into the other side
    into_shadow = cv2.distanceTransform(truth.astype(np.uint8), cv2.DIST_L2, 3)
    into_lit = cv2.distanceTransform((~truth).astype(np.uint8), cv2.DIST_L2, 3)
    assert into_shadow[lit_core].max() < 3 and into_lit[shadow_core].max() < 3
    assert shadow_core.sum() < shadow.sum() and lit_core.sum() < lit.sum()


def test_a_roi_limits_the_parts() -> None:
    img, truth = _shade(_soil(np.random.default_rng(1)), 0.5, 0.0)
    inside = np.zeros(truth.shape, bool)
    cv2.circle(inside.view(np.uint8), (160, 120), 110, 1, -1)
    parts = shadow_regions(img, inside)
    assert len(parts) == 2
    for part, core in parts:
        assert not np.any(part & ~inside) and not np.any(core & ~part)


def test_no_shadow_no_parts() -> None:
    rng = np.random.default_rng(2)
    assert shadow_regions(_soil(rng).astype(np.uint8), np.ones((240, 320), bool)) == []
    # a faint shade (a thin cloud's edge, vignetting) is not a cast shadow
    img = _soil(rng)
    img[:, 160:] *= 0.8
    assert shadow_regions(img.astype(np.uint8), np.ones((240, 320), bool)) == []


def test_a_large_plant_is_not_taken_for_the_lit_part() -> None:
    """A bright plant filling a third of a dark soil's frame is a brightness class of its own;
    leaving green pixels out of the map keeps it from being a "lit part"."""
    img = _soil(np.random.default_rng(3), bgr=(40, 55, 75)).astype(np.uint8)
    for a in np.linspace(0, 2 * np.pi, 7)[:-1]:
        c = (160 + 55 * math.cos(a), 120 + 55 * math.sin(a))
        cv2.ellipse(img, (round(c[0]), round(c[1])), (55, 22), math.degrees(a), 0, 360, (90, 200, 120), -1)
    assert shadow_regions(img, np.ones((240, 320), bool)) == []


def test_stones_or_straw_on_dark_soil_are_not_a_shadow() -> None:
    rng = np.random.default_rng(4)
    img = _soil(rng, bgr=(45, 60, 80)).astype(np.uint8)
    for _ in range(60):  # pale stones and straw, each well below a cell
        x, y = rng.integers(0, 320), rng.integers(0, 240)
        cv2.circle(img, (int(x), int(y)), int(rng.integers(2, 6)), (170, 180, 190), -1)
        a = rng.uniform(0, np.pi)
        cv2.line(img, (int(x), int(y)), (int(x + 25 * math.cos(a)), int(y + 25 * math.sin(a))), (120, 190, 215), 2)
    assert shadow_regions(img, np.ones((240, 320), bool)) == []


@pytest.mark.parametrize("seed", range(6))
def test_cell_medians_are_the_medians_of_each_cells_log_grey(seed: int) -> None:
    """The histogram medians equal numpy's median of each cell's soil log(grey + 8) values: odd and
    even counts, ties, empty cells, cells cut by the window's edge, every pixel or every other one."""
    rng = np.random.default_rng(seed)
    for _ in range(20):
        h, w = (int(v) for v in rng.integers(10, 90, 2))
        cs, step = int(rng.integers(3, 25)), int(rng.integers(1, 3))
        grey = rng.integers(0, 256, (h, w)).astype(np.uint8)
        if seed % 2:
            grey = (grey // 64 * 64).astype(np.uint8)  # many ties
        soil = rng.random((h, w)) < rng.uniform(0.0, 1.0)
        ny, nx = -(-h * step // cs), -(-w * step // cs)
        med, n = _cell_medians(grey, soil, cs, ny, nx, step)
        lg = np.log(grey.astype(np.float32) + np.float32(8.0))
        rows, cols = np.arange(h) * step // cs, np.arange(w) * step // cs
        for j in range(ny):
            for i in range(nx):
                v = lg[np.ix_(rows == j, cols == i)][soil[np.ix_(rows == j, cols == i)]]
                assert n[j, i] == len(v)
                if len(v):
                    assert med[j, i] == np.median(v)
                else:
                    assert np.isnan(med[j, i])


# ---- the detector on frames of bench/field_photo_weeds.py (an independent photo renderer)

# (seed, case, the photographer's shadow forced, with a ROI): "no_plant" before the look into each
# part. Measured with it: 0.03 S from the crown (a fat-hen half in the photographer's shadow), grass
# 0.004 S; forced (`--person-shadow`): a plantain, a thistle and a clover within 0.2 S
SHADOWED = [(0, 158, False, True), (0, 158, False, False), (4, 152, False, False),
            (0, 51, True, False), (0, 76, True, False), (0, 33, True, True)]


@pytest.mark.parametrize("seed, i, forced, with_roi", SHADOWED)
def test_plant_hidden_by_a_shadowed_soil_statistics_is_found(seed, i, forced, with_roi, monkeypatch) -> None:
    fpw = field_photos()
    img, truth, S, notes = fpw.render(np.random.default_rng([seed, i]), fpw.KINDS[i % len(fpw.KINDS)], forced)
    assert "person_shadow" in notes["light"]
    roi = fpw.roi_near(seed, i, truth, S) if with_roi else None
    det = detect_centre(img, roi)
    assert crown_off(det, truth, S) < 0.2, det
    monkeypatch.setattr(detector, "_in_shadow_parts", lambda *a, **k: None)
    # (since session 29 the whole window's second look finds the forced-shadow clover (0, 33) with
    # its ROI by the large-teal rule too, 0.02 S off: that rule off, only the part look finds it)
    monkeypatch.setattr(candidates, "LTEAL_GR", math.inf)
    assert detect_centre(img, roi).reason == "no_plant"


# (seed, case, the photographer's shadow forced): no ROI; the whole window chose a small sunlit plant
# while the weed lies in the shadow, 1.48 and 1.24 S from its crown. Measured with the part look after
# an answer: a fat-hen 0.27 S, another 0.05 S (the first's tree median runs on a mask cut at the part's edge)
OUTSHONE = [(0, 18, False, 0.35), (0, 38, True, 0.1)]


@pytest.mark.parametrize("seed, i, forced, tol", OUTSHONE)
def test_plant_in_a_shadow_outscores_a_small_sunlit_one(seed, i, forced, tol, monkeypatch) -> None:
    fpw = field_photos()
    img, truth, S, notes = fpw.render(np.random.default_rng([seed, i]), fpw.KINDS[i % len(fpw.KINDS)], forced)
    assert "person_shadow" in notes["light"]
    det = detect_centre(img)
    assert crown_off(det, truth, S) < tol, det
    monkeypatch.setattr(detector, "SHADOW_GAIN", math.inf)  # no part's plant can replace an answer
    det = detect_centre(img)
    assert det.reason is None and crown_off(det, truth, S) > 1.0, det


def test_bare_soil_in_a_shadow_stays_bare() -> None:
    """20 bare frames (stones, straw, litter, moss, dead leaves) under the photographer's shadow
    (`bench/field_photo_weeds.py --person-shadow --bare`), with the bench's ROI: no plant on ≥ 18
    (measured 19, before and after the look into each part: the one answer is moss; over 60 frames
    57 with a ROI, 50 without, before and after)."""
    fpw = field_photos()
    bare = 0
    for i in range(20):
        img, truth, S, _ = fpw.render(np.random.default_rng([0, i]), fpw.KINDS[i % len(fpw.KINDS)], True, True)
        bare += detect_centre(img, fpw.roi_near(0, i, truth, S)).reason == "no_plant"
    assert bare >= 18, bare


def test_olive_straws_crossing_in_a_shadow_are_no_plant(monkeypatch) -> None:
    """Bench seed 1 bare case 86: two dark olive straws cross in a shadow across the TROI. In the
    shadowed part alone (lower σ) they pass the colour rules, as 0.3 % of the part with g_raw −0.03;
    a plant found in a part must be green in raw colours unless ≥ SHADOW_BIG of it."""
    from capm_field.camera import PinholeCamera
    from capm_field.config import CameraConfig, TaskConfig
    from capm_field.detector import roi_from_troi
    from sim_bench.perception_bench import make_case

    cam = PinholeCamera.from_config(CameraConfig())
    case = make_case(1, 86, cam, TaskConfig().delta, True)
    img = case.scene.render(case.T, cam)
    roi = roi_from_troi(cam, case.T, case.troi_centre, case.troi_radius)
    assert detect_centre(img, roi).reason == "no_plant"
    monkeypatch.setattr(detector, "SHADOW_RAW_G", -1.0)
    assert detect_centre(img, roi).reason is None
