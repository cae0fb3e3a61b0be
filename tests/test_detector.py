"""Weed-centre detector: accuracy on rendered NSV views, bare soil, bad inputs, hand-made photos."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig, TaskConfig
from capm_field.detector import Detection, Roi, detect_centre, ground_centre, roi_from_troi
from capm_field.roi import as_roi
from sim_bench.perception_bench import make_case, pose_from_axis
from sim_bench.plants import WEED_KINDS

from field_photos import bench_module, crown_off, field_photos

CAM = PinholeCamera.from_config(CameraConfig())
FIX = Path(__file__).parent / "fixtures" / "plants"


N_PER_KIND = 12  # default batch: 12 NSV views per weed kind + 12 bare-soil views (~20 s)


def _run(kind: str, n: int, seed: int = 11) -> tuple[list[float], int, list]:
    """(ground errors in mm of the detections, misses, reasons) on n bench cases of one kind."""
    errs, missed, reasons = [], 0, []
    i = 0
    while len(reasons) < n:
        case = make_case(seed, 4 * i + WEED_KINDS.index(kind) if kind != "bare" else i, CAM, 0.1, bare=kind == "bare")
        i += 1
        if case is None:
            continue
        assert case.kind == kind
        det = detect_centre(case.scene.render(case.T, CAM), roi_from_troi(CAM, case.T, case.troi_centre, case.troi_radius))
        reasons.append(det.reason)
        if kind == "bare":
            continue
        g = ground_centre(CAM, case.T, det)
        if det.reason is not None or g is None:
            missed += 1
            continue
        errs.append(float(np.linalg.norm(g - case.scene.weeds[0].centre) * 1000))
    return errs, missed, reasons


# Per-kind guards at the level measured on the bench (docs/perception.md), not the targets: a
# change that makes the detector worse fails here. The targets themselves are checked by the
# slow batch below, marked xfail(strict) while they are not met.
GUARDS = {  # kind: (max misses of N_PER_KIND, max median error mm, max wrong (> 30 mm))
    "rosette": (1, 4.5, 1),  # measured on this batch: 0 missed, median 2.5 mm, 0 wrong (was 3.4 mm, 1)
    "seedling": (1, 4.5, 2),  # 1 missed, 2.2 mm, 1 wrong (was 0, 4.4 mm, 1)
    "grass": (1, 8.0, 4),  # 0, 5.5 mm, 3 wrong (was 6.2 mm)
    "clover": (1, 15.0, 2),  # 0, 11.5 mm, 0 wrong (was 16.3 mm, 2)
}


@pytest.mark.parametrize("kind", WEED_KINDS)
def test_accuracy_per_kind(kind: str) -> None:
    errs, missed, _ = _run(kind, N_PER_KIND)
    max_miss, max_med, max_wrong = GUARDS[kind]
    assert missed <= max_miss, (kind, missed)
    assert errs and np.median(errs) <= max_med, (kind, np.median(errs))
    assert sum(e > 30.0 for e in errs) <= max_wrong, (kind, sorted(errs))


def test_bare_soil_gives_no_plant() -> None:
    """Target: "no plant" on ≥ 95 % of bare-soil views (42 views of two seeds; measured 42/42)."""
    _, _, a = _run("bare", N_PER_KIND, seed=12)
    _, _, b = _run("bare", 30, seed=22)
    reasons = a + b
    assert reasons.count("no_plant") >= 0.95 * len(reasons), reasons


def _soil(rng, shape=(480, 640), colour=(95, 110, 150)) -> np.ndarray:
    return np.clip(cv2.GaussianBlur(rng.normal(0, 12, (*shape, 3)), (0, 0), 1.0) + colour, 0, 255).astype(np.uint8)


def test_grey_stones_on_reddish_soil_are_not_plants() -> None:
    """White balance towards a typical soil turns neutral stones cyan-green: not a plant."""
    rng = np.random.default_rng(5)
    img = _soil(rng, colour=(80, 90, 150))
    for c in ((300, 200), (360, 260), (250, 300)):
        cv2.circle(img, c, 14, (170, 175, 175), -1, cv2.LINE_AA)
    det = detect_centre(img, Roi.from_ellipse((320, 240), (200, 200)))
    assert det.reason == "no_plant", det


@pytest.mark.parametrize("stone", [(120, 125, 125), (200, 200, 195), (150, 150, 150)])
def test_grey_stones_on_purplish_soil_are_not_plants(stone) -> None:
    """On a soil whose green is its weakest channel, the white balance turns neutral stones
    green in every colour test after it; before it they are neutral (G − (R + B)/2 ≈ 0)."""
    rng = np.random.default_rng(11)
    img = _soil(rng, colour=(100, 90, 150))
    for c, r in (((300, 200), 16), ((360, 260), 12), ((250, 300), 18)):
        cv2.circle(img, c, r, stone, -1, cv2.LINE_AA)
    det = detect_centre(img, Roi.from_ellipse((320, 240), (200, 200)))
    assert det.reason == "no_plant", det


def _rosette_touching_a_stone(seed: int, plant: bool = True) -> tuple[np.ndarray, np.ndarray, float]:
    """(image, true centre, plant size) of a green rosette on dark reddish soil, touched by a
    larger pale stone that the soil white balance turns green (other renderer seed 0 case 43)."""
    rng = np.random.default_rng(seed)
    img = _soil(rng, (720, 1280), colour=(41, 44, 68))
    c = np.array([640.0 + rng.uniform(-80, 80), 360.0 + rng.uniform(-60, 60)])
    L = 45.0
    a = rng.uniform(0, 2 * np.pi)
    R = 1.3 * L
    ang = rng.uniform(0, 2 * np.pi, 9)
    pts = c + (0.8 * L + R) * np.array([math.cos(a), math.sin(a)]) + R * rng.uniform(0.8, 1.0, 9)[:, None] * np.c_[np.cos(ang), np.sin(ang)]
    cv2.fillPoly(img, [cv2.convexHull(np.round(pts).astype(np.int32))], (150, 160, 170), cv2.LINE_AA)
    if plant:
        _lens_rosette(img, rng, c, L, (46, 143, 82))
    return cv2.GaussianBlur(img, (0, 0), 1.0), c, 2 * L


@pytest.mark.parametrize("seed", [1, 5, 6])
def test_plant_touching_a_stone_the_white_balance_made_green_is_found(seed: int, monkeypatch) -> None:
    """A plant and a larger neutral stone in one stage-1 component: the component's median colour
    is the stone's (not greener than magenta in the camera's colours), so it was dropped whole
    ("no_plant"). Its green part alone is judged instead (`plant_choice._green_part`); the stone
    alone stays no plant."""
    import capm_field.plant_choice as choice_mod

    img, c, S = _rosette_touching_a_stone(seed)
    det = detect_centre(img)
    assert det.reason is None and np.hypot(*(np.array(det.pixel) - c)) < 0.15 * S, (det, c)
    assert detect_centre(_rosette_touching_a_stone(seed, plant=False)[0]).reason == "no_plant"
    monkeypatch.setattr(choice_mod, "SPLIT_GREEN", False)
    assert detect_centre(img).reason == "no_plant"


def test_straw_is_not_a_plant() -> None:
    """A straight olive-yellow straw piece (greenish after white balance) is not a weed."""
    rng = np.random.default_rng(7)
    img = _soil(rng, colour=(70, 80, 120))
    cv2.line(img, (250, 260), (390, 210), (60, 150, 150), 5, cv2.LINE_AA)
    det = detect_centre(img, Roi.from_ellipse((320, 240), (200, 200)))
    assert det.reason == "no_plant", det


@pytest.mark.parametrize("seed, index, kind, tol",
                         [(3, 80, "rosette", 0.01), (1, 1, "seedling", 0.005), (0, 269, "seedling", 0.005),
                          (2, 280, "rosette", 0.01), (3, 13, "seedling", 0.005)])
def test_second_look_bench_weeds_are_found(seed: int, index: int, kind: str, tol: float) -> None:
    """Bench weeds only the second look finds, each located within `tol` m.

    Seed 3 case 80: a pale yellow-green rosette covering ~5 % of the window on a bright, grainy
    sand stands only 3.3 soil σ above it in −a*, short of the 8 σ the large-candidate rule asked;
    at that size its colour (gb 0.12, saturation 0.36) is enough. Seed 1 case 1: a small seedling
    under 4 × the minimum component area, so a distractor 63 mm away was answered (VIVID_AREA 4.0
    until session 13). Seed 0 case 269: a dull green seedling on pale grey soil, 14 σ above it
    in −a* but of saturation 0.2899, under LC_SAT: "no_plant" until LC_SAT_PALE. Seed 2 case 280
    (a pale rosette, 36 mm off) and seed 3 case 13 (a seedling, 18 mm off): G* segments a part of
    the plant, −a* the same plant whole at 2.0× and 2.3× its area but < 1.5× its score, which
    WHOLE_GAIN takes."""
    case, img, roi = _bench_frame(seed, index, kind)
    det = detect_centre(img, roi)
    assert det.reason is None, det
    assert np.linalg.norm(ground_centre(CAM, case.T, det) - case.scene.weeds[0].centre) < tol


def _bench_frame(seed: int, index: int, kind: str):
    """A bench weed case of `kind`, its rendered NSV frame and its ROI."""
    case = make_case(seed, index, CAM, TaskConfig().delta, False)
    assert case.kind == kind
    return case, case.scene.render(case.T, CAM), roi_from_troi(CAM, case.T, case.troi_centre, case.troi_radius)


def _bench_weed(seed: int, index: int, kind: str = "clover"):
    """A bench weed frame: a function that runs the detector on it (with its ROI) and returns
    (ground error in m, stage-2 estimator)."""
    case, img, roi = _bench_frame(seed, index, kind)

    def locate() -> tuple[float, str]:
        dbg: dict = {}
        det = detect_centre(img, roi, debug=dbg)
        assert det.reason is None, det
        return float(np.linalg.norm(ground_centre(CAM, case.T, det) - case.scene.weeds[0].centre)), dbg["method"]

    return locate


def test_two_leaf_rosette_in_a_line_is_no_straw(monkeypatch) -> None:
    """Bench seed 4 case 40: a dark-green rosette of two leaves in a line (elongation 5.9 at full
    resolution, past the straw rule's 5.0) with min(g_raw, gr) 0.05: above bench straw (≤ 0.044),
    so `green_blade` spares it. Found within 10 mm; at the old BLADE_GREEN 0.06, "no plant" unless its waist
    between the two leaves spares it too (`plant_choice.WAISTED_PAIR`, session 74)."""
    import capm_field.candidates as cand
    import capm_field.plant_choice as choice

    case, img, roi = _bench_frame(4, 40, "rosette")
    det = detect_centre(img, roi)
    assert det.reason is None, det
    assert np.linalg.norm(ground_centre(CAM, case.T, det) - case.scene.weeds[0].centre) < 0.010
    monkeypatch.setattr(cand, "BLADE_GREEN", 0.06)
    assert detect_centre(img, roi).reason is None
    monkeypatch.setattr(choice, "WAISTED_PAIR", False)
    assert detect_centre(img, roi).reason == "no_plant"


@pytest.mark.parametrize("seed, index", [(5, 27)])
def test_clover_of_many_vote_peaks_is_no_fan(seed: int, index: int, monkeypatch) -> None:
    """A bench clover (seed 5 case 27) whose trefoils pass the fan test from a vote peak on the
    plant's rim; its leaf axes converge at 6 points, and seen from the peak they span 85–95°: wider
    than the dense grass fans of that many peaks (FAN_DENSE_GAP). With the rule it is located
    13.0 mm off (42.5 mm as a fan; since session 58, whose second look also runs on it, 42.9 mm as a
    `wide_fan`, the same test at the leaves' scale). (Case 147, the other clover the rule was made for, has
    been located by its trefoil hubs without the rule too since −a* follows CIE's formulas, session 34.)"""
    import capm_field.fan_apex as fan

    locate = _bench_weed(seed, index)
    err, method = locate()
    assert err < 0.015 and method != "fan_apex", (err, method)
    monkeypatch.setattr(fan, "FAN_DENSE_GAP", 0.0)
    err, method = locate()
    assert err > 0.03 and method in ("fan_apex", "wide_fan"), (err, method)


@pytest.mark.parametrize("seed, index", [(6, 214), (7, 74)])
def test_wide_one_peak_grass_fan_is_centred_at_its_base(seed: int, index: int, monkeypatch) -> None:
    """Bench grass tufts whose thin blades fan over ~150–200° from one base (one leaf-axis vote
    peak): `fan_apex` answers at the base (0.9 and 5.3 mm off). Under the old single pixel gap
    (0.8 × 3.6 rad for every plant) they went to `petiole_centre` / `line_hub`, 16.9 and 30.8 mm off
    (with the line-of-sight check of session 59, case 74's `line_hub` answer is taken back to 4.2 mm:
    the old gaps are measured without it)."""
    import capm_field.centre_cascade as cascade
    import capm_field.fan_apex as fan

    locate = _bench_weed(seed, index, "grass")
    err, method = locate()
    assert err < 0.008 and method == "fan_apex", (err, method)
    monkeypatch.setattr(cascade, "STAR_CHECK", False)
    monkeypatch.setattr(fan, "FAN_PIX_GAP_ONE", fan.FAN_PIX_GAP)
    monkeypatch.setattr(fan, "FAN_GAP", 3.6)
    err, method = locate()
    assert err > 0.012 and method != "fan_apex", (err, method)


@pytest.mark.parametrize("seed, index", [(2, 250), (5, 90)])
def test_blurred_dense_grass_fan_is_centred_at_its_base(seed: int, index: int, monkeypatch) -> None:
    """Bench grass tufts whose blades blur into one blob towards the base: mean half-width 0.077 and
    0.063 of the size, round for step 1's fan test. `wide_fan` (the fan test again before the medians,
    ≥ 3 far tips) answers 4.6 and 6.5 mm off; without it the tree median lands mid-fan, 34.9 and 30.6 mm."""
    import capm_field.centre_cascade as cc

    locate = _bench_weed(seed, index, "grass")
    err, method = locate()
    assert err < 0.010 and method == "wide_fan", (err, method)
    monkeypatch.setattr(cc, "WIDE_FAN_ROUND", 0.0)
    err, method = locate()
    assert err > 0.030 and method != "wide_fan", (err, method)


@pytest.mark.parametrize("seed, index", [(3, 139), (6, 223)])
def test_clover_petioles_meeting_in_a_v_are_split(seed: int, index: int, monkeypatch) -> None:
    """Bench clovers whose two visible petioles meet in a V: `petiole_centre` saw one bent ridge,
    no straight piece, and the median of the parts answered 20.1 and 25.6 mm off. Split by the
    ridge's direction (`split`, late in the cascade), the V's arms meet at the centre: 0.3 and 2.3 mm.
    The floor on the longest supporting piece is what the test turns off to see the old answer."""
    import capm_field.plant_centre as pc

    locate = _bench_weed(seed, index)
    err, method = locate()
    assert err < 0.005 and method == "petiole_split", (err, method)
    monkeypatch.setattr(pc, "PET_SPLIT_LEN", 10.0)
    import capm_field.centre_cascade as cascade
    monkeypatch.setattr(cascade, "HUB_PETIOLES", False)  # (which also finds these, within 2 mm)
    err, method = locate()
    assert err > 0.015 and method != "petiole_split", (err, method)


def test_clover_of_two_vote_peaks_keeps_its_stalks(monkeypatch) -> None:
    """Bench seed 4 case 167: a clover of thin parts (roundness 0.022) whose stalks `stalk_centre`
    finds (0.6 mm off). Seen from its strongest vote peak it leaves a 130° gap, which the wide-fan
    pixel test for one-peak blades would pass (38.5 mm off as a fan); its votes have 2 peaks."""
    import capm_field.fan_apex as fan

    locate = _bench_weed(4, 167)
    err, method = locate()
    assert err < 0.003 and method == "stalk_centre", (err, method)
    monkeypatch.setattr(fan, "FAN_PIX_GAP", fan.FAN_PIX_GAP_ONE)
    err, method = locate()
    assert err > 0.03 and method == "fan_apex", (err, method)


@pytest.mark.parametrize("seed, index, kind", [(5, 178, "grass"), (6, 32, "rosette")])
def test_line_hub_far_off_the_plants_middle_is_not_its_centre(seed: int, index: int, kind: str, monkeypatch) -> None:
    """Bench seed 5 case 178 (a grass tuft of thick blades) and seed 6 case 32 (a rosette):
    `line_hub`'s peak lay where thin parts near the plant's rim cross (a blade's tip, a leaf's
    stalk), 0.24–0.25 of the plant's size from its mask centroid, 46.2 and 28.9 mm off. Hubs that
    far off the middle (> LH_MAX_OFF) are refused, and the tree median answers: 4.9 and 0.9 mm.
    (Since session 42 `fan_apex` takes the grass first, 4.0 mm off; the old fan gaps keep it on
    line_hub's path here.) Since session 59 the line-of-sight check would take both far hubs back too
    (6.7 and 2.4 mm): the bound is measured without it."""
    import capm_field.centre_cascade as cascade
    import capm_field.fan_apex as fan
    import capm_field.plant_centre as pc

    monkeypatch.setattr(fan, "FAN_PIX_GAP_ONE", fan.FAN_PIX_GAP)
    monkeypatch.setattr(fan, "FAN_GAP", 3.6)
    locate = _bench_weed(seed, index, kind)
    err, method = locate()
    assert err < 0.01 and method != "line_hub", (err, method)
    monkeypatch.setattr(cascade, "STAR_CHECK", False)
    monkeypatch.setattr(pc, "LH_MAX_OFF", 9.0)
    err, method = locate()
    assert err > 0.025 and method == "line_hub", (err, method)


@pytest.mark.parametrize("seed, index, kind", [(1, 34, "grass"), (1, 195, "clover"), (3, 259, "clover")])
def test_leaf_axis_votes_spread_over_the_plant_do_not_pull_the_tree_median(seed: int, index: int, kind: str, monkeypatch) -> None:
    """Bench seed 1 cases 34 (grass) and 195 (clover), seed 3 case 259 (clover): their leaf-axis
    votes pile up nowhere (7.2, 5.1 and 5.6 % of them within 0.08 × size of the peak; mostly
    8–12 % on rosettes and grass fans whose axes meet), yet their maximum decided the tree
    median: 31.0, 17.0 and 24.3 mm off. Weighted by how concentrated they are (VOTE_CONC): 4.3,
    3.3 and 5.9 mm. (Measured with every tip counting 1: since `TIP_SPREAD` the grass's bunched tips
    count less and its answer is 30.9 mm off, a loss its comment counts. Since session 58 the second
    look takes the grass, 7.1 mm off by `fan_apex`: the first look's plant is kept here as before.)"""
    import capm_field.detector as detector
    import capm_field.tree_median as tm

    monkeypatch.setattr(tm, "TIP_SPREAD", 0.0)
    monkeypatch.setattr(detector, "PALE_G90", 0.05)  # (session 58's second look on pale first choices)
    monkeypatch.setattr(detector, "WHOLE_GAIN", 1.5)
    locate = _bench_weed(seed, index, kind)
    err, method = locate()
    assert err < 0.01 and method == "tree_median", (err, method)
    monkeypatch.setattr(tm, "VOTE_CONC", None)
    err, method = locate()
    assert err > 0.015 and method == "tree_median", (err, method)


@pytest.mark.parametrize("seed, index, name, old", [(11, 207, "G_GAP", 4.5), (7, 155, "G_HUB", 0.06)])
def test_clover_trefoils_to_one_side_or_faint_keep_their_rays(seed: int, index: int, name: str, old: float, monkeypatch) -> None:
    """Bench seed 11 case 207: three trefoils on one side of the centre (their largest gap round
    it 4.54 rad); seed 7 case 155: four faint ones (mean hub strength 0.060). Their rays meet at
    the centre: 4.1 and 5.9 mm off. Under session 59's gate (gap ≤ 4.5 rad, strength ≥ 0.06)
    `compound_centre` declined both and the medians of the parts answered, 31.9 and 36.6 mm off."""
    import capm_field.compound_leaf as cl

    locate = _bench_weed(seed, index)
    err, method = locate()
    assert err < 0.010 and method == "compound_centre", (err, method)
    monkeypatch.setattr(cl, name, old)
    err, method = locate()
    assert err > 0.030 and method != "compound_centre", (err, method)


def test_clover_of_small_trefoils_with_one_vote_peak_gets_its_hubs(monkeypatch) -> None:
    """Bench seed 7 case 23: small trefoils on long tan petioles that neither look segments.
    The plant reads as thin (r 0.021) and its leaf axes show one vote peak, so the hub estimators
    used to be skipped and the tree median slid onto a trefoil (38.0 mm off; 29.7 mm since its
    votes count by how much they pile up). Its parts are separate and its strongest three-lobed
    hub (0.20) reaches ONE_PEAK_HUB: 1.9 mm."""
    import capm_field.centre_cascade as cascade

    locate = _bench_weed(7, 23)
    err, method = locate()
    assert err < 0.005 and method == "compound_centre", (err, method)
    monkeypatch.setattr(cascade, "ONE_PEAK_HUB", 9.0)
    monkeypatch.setattr(cascade, "HUB_PETIOLES", False)  # (which also finds it, within 1 mm)
    err, method = locate()
    assert err > 0.025 and method == "tree_median", (err, method)


@pytest.mark.parametrize("seed, index", [(2, 214), (3, 210)])
def test_olive_straw_on_bench_bare_soil_is_not_a_plant(seed: int, index: int) -> None:
    """Bench bare-soil scenes whose only candidates are long straws that the scene's light
    made olive (raw G − max(R, B) ≈ −0.010 … −0.016 of the sum, elongation 9–16): straw, not a
    weed (the weeds' own long pieces measured ≥ −0.0098). With STRAW_RAW at −0.02 both were
    answered as plants (confidence 0.42)."""
    bare = set(np.random.default_rng(seed).choice(300, 45, replace=False).tolist())
    assert index in bare
    case = make_case(seed, index, CAM, TaskConfig().delta, True)
    img = case.scene.render(case.T, CAM)
    det = detect_centre(img, roi_from_troi(CAM, case.T, case.troi_centre, case.troi_radius))
    assert det.reason == "no_plant", det


def test_pale_soil_patch_is_not_a_plant() -> None:
    """A fresh bare-soil scene (perception_failures --seed 7 --bare-share 1.0, case 5) whose
    second look holds a large soil patch of saturation 0.265, local contrast 4.1 σ and only
    6.3 σ above the soil in −a*: below LC_SAT it needs LC_SIGMA_PALE (without that margin it
    was answered as a plant, confidence 0.87)."""
    case = make_case(7, 5, CAM, TaskConfig().delta, True)
    img = case.scene.render(case.T, CAM)
    det = detect_centre(img, roi_from_troi(CAM, case.T, case.troi_centre, case.troi_radius))
    assert det.reason == "no_plant", det


def test_dull_grey_green_plant_far_above_the_soil_is_a_plant() -> None:
    """Grey-green leaves (overcast light, glaucous leaves; saturation ≈ 0.2, G only a little
    above R and B) standing ≥ 12 σ above a smooth soil are a plant, not a stone."""
    rng = np.random.default_rng(12)
    img = np.clip(cv2.GaussianBlur(rng.normal(0, 3, (480, 640, 3)), (0, 0), 1.0) + (80, 95, 120), 0, 255).astype(np.uint8)
    c = np.array([320.0, 240.0])
    _lens_rosette(img, rng, c, 70.0, (100, 120, 98))  # BGR: G above R by 22 and above B by 20
    det = detect_centre(img)
    assert det.reason is None and np.hypot(*(np.array(det.pixel) - c)) < 25, det  # found (the centre: other tests)


def _yellow_green_seedling(img: np.ndarray, c: np.ndarray) -> None:
    """Three yellow-green leaves (G ≈ R) of 30–45 px from `c`."""
    for a, L in ((-1.2, 45), (1.9, 40), (0.4, 30)):
        d = np.array([np.cos(a), np.sin(a)])
        m = c + d * L / 2
        cv2.ellipse(img, (int(m[0]), int(m[1])), (L // 2, L // 5), np.degrees(a), 0, 360, (35, 118, 116), -1, cv2.LINE_AA)


def test_yellow_green_seedling_on_olive_soil() -> None:
    """A vivid yellow-green seedling (G ≈ R, as in the bench demo's W12) on grey-olive soil:
    G − max(R, B) leaves it at the soil's level, the CIELAB second look finds it."""
    import capm_field.detector as det_mod

    rng = np.random.default_rng(9)
    img = _soil(rng, colour=(95, 110, 115))
    c = np.array([320.0, 250.0])
    _yellow_green_seedling(img, c)
    roi = Roi.from_ellipse((320, 240), (200, 200))
    assert det_mod._detect(img, roi).reason == "no_plant"  # the first look alone misses it
    det = detect_centre(img, roi)
    assert det.reason is None and np.hypot(*(np.array(det.pixel) - c)) < 8, det


def _cotyledons(img: np.ndarray, c: np.ndarray, col) -> None:
    """Two opposite cotyledons, 70 px long and 36 px wide, meeting at `c`."""
    for a in (-1.3, 1.84):
        m = c + 35.0 * np.array([math.cos(a), math.sin(a)])
        cv2.ellipse(img, (int(m[0]), int(m[1])), (35, 18), math.degrees(a), 0, 360, col, -1, cv2.LINE_AA)


@pytest.mark.parametrize("roi", [None, Roi.from_ellipse((320, 240), (260, 260))])
def test_cyan_tinted_seedling_on_reddish_soil(roi, monkeypatch) -> None:
    """Blue-green cotyledons with blue at green's level (cool light, a glaucous bloom) on a
    reddish soil, whose white balance lifts blue further: not green above blue, so neither G*
    nor the teal rule takes them; −a* segments them and the cyan rule (far greener than red,
    saturated) makes them a plant."""
    import capm_field.candidates as cand

    rng = np.random.default_rng(1)
    img = _soil(rng, colour=(70, 90, 150))
    c = np.array([320.0, 240.0])
    _cotyledons(img, c, (125, 120, 55))  # BGR: B 5 above G, R far below
    det = detect_centre(img, roi)
    assert det.reason is None and np.hypot(*(np.array(det.pixel) - c)) < 3, det
    monkeypatch.setattr(cand, "CYAN_GR", 9.0)  # without the rule: nothing plant-like
    assert detect_centre(img, roi).reason == "no_plant"


@pytest.mark.parametrize("seed", [0, 3])
def test_teal_leaves_in_a_line_are_no_straw(seed, monkeypatch) -> None:
    """Two narrow teal leaves meeting tip to tip (elongation > 5, like straw): blue near green
    keeps G − max(R, B) at ~0.03, below the green-blade rule's 0.06, but the pair is far greener
    than red (gr ~0.2; long non-weed pieces on the bench ≤ 0.035). Found; without the teal
    clause the straw rule drops it."""
    import capm_field.candidates as cand

    rng = np.random.default_rng(seed)
    img = _soil(rng, colour=(110, 112, 115))
    c = np.array([320.0, 240.0])
    for a in (0.4 + seed, 0.4 + seed + math.pi):
        m = c + 44.0 * np.array([math.cos(a), math.sin(a)])
        cv2.ellipse(img, (int(m[0]), int(m[1])), (44, 8), math.degrees(a), 0, 360, (130, 140, 60), -1, cv2.LINE_AA)
    det = detect_centre(img)
    # found; the centre of a pair in a line is loose (all its leaf-axis votes lie on one line)
    length = 4 * 44.0  # tip to tip
    assert det.reason is None and np.hypot(*(np.array(det.pixel) - c)) < 0.2 * length, det
    monkeypatch.setattr(cand, "BLADE_TEAL_RAW", 9.0)
    assert detect_centre(img).reason == "no_plant"


@pytest.mark.parametrize("seed", [0, 3])
def test_uneven_trefoils_join_within_a_troi(seed, monkeypatch) -> None:
    """A clover whose petioles do not show: one large trefoil and two of 0.30–0.36 its area, too far
    apart for stage 1 to group, close enough to be one plant. Within a ROI they join the large one
    (PART_MERGE), so the centre is sought between all three; without the rule, on the large one."""
    import capm_field.detector as det_mod

    rng = np.random.default_rng(seed)
    img = _soil(rng)
    c = np.array([320.0, 240.0])
    a0 = 0.3
    mids = []  # middle leaflets' centres
    for k, (dist, s) in enumerate(((66, 40), (54, 24), (52, 22))):
        a = a0 + k * 2 * np.pi / 3
        u = np.array([math.cos(a), math.sin(a)])
        _trefoil(img, c + dist * u, a, s, (50, 140, 60))
        mids.append(c + (dist + 0.55 * s) * u)
    roi = Roi.from_ellipse((330, 235), (150, 150))

    def chosen(dbg: dict) -> list[bool]:  # whether each trefoil lies in the plant located
        return [bool(dbg["mask_full"][int(m[1]), int(m[0])] == 2) for m in mids]

    dbg: dict = {}
    det = detect_centre(img, roi, debug=dbg)
    assert det.reason is None and chosen(dbg) == [True, True, True], det
    d_all = np.hypot(*(np.array(det.pixel) - c))
    monkeypatch.setattr(det_mod, "PART_MERGE", 9.0)
    dbg = {}
    det = detect_centre(img, roi, debug=dbg)
    assert chosen(dbg) == [True, False, False]
    assert np.hypot(*(np.array(det.pixel) - c)) > d_all + 10


@pytest.mark.parametrize("seed", [0, 3])
def test_trefoils_of_one_colour_join_across_long_petioles(seed, monkeypatch) -> None:
    """Three trefoils of one colour and uneven size 50 px from the centre, petioles unseen: farther
    apart than MERGE_GAP (0.5) × a trefoil's diameter, so without MERGE_GAP_SAME the centre is
    sought on the largest (~50 px off); with it they are one plant, its centre within 2 px (bench
    seed 4 case 167: 38.5 → 0.6 mm). Two trefoils as far apart join if of one colour, not if the
    smaller is yellower (a neighbouring plant of another kind)."""
    import capm_field.detector as det_mod

    def clover(angles, sizes, cols) -> tuple[Detection, list[bool]]:
        img = _soil(np.random.default_rng(seed))
        c = np.array([320.0, 240.0])
        mids = []
        for a, s, col in zip(angles, sizes, cols):
            u = np.array([math.cos(a), math.sin(a)])
            _trefoil(img, c + 50 * u, a, s, col)
            mids.append(c + (50 + 0.55 * s) * u)
        dbg: dict = {}
        det = detect_centre(img, Roi.from_ellipse((330, 235), (180, 180)), debug=dbg)
        return det, [bool(dbg["mask_full"][int(m[1]), int(m[0])] == 2) for m in mids]

    green, yellower = (50, 140, 60), (90, 150, 50)
    three = ((0.3, 0.3 + 2 * np.pi / 3 + 0.25, 0.3 + 4 * np.pi / 3), (28, 20, 19), (green,) * 3)
    det, joined = clover(*three)
    assert det.reason is None and joined == [True] * 3 and math.hypot(det.pixel[0] - 320, det.pixel[1] - 240) < 2.0, det
    det, joined = clover((0.3, 0.3 + np.pi + 0.25), (28, 20), (green, green))
    assert det.reason is None and joined == [True, True], det
    det, joined = clover((0.3, 0.3 + np.pi + 0.25), (28, 20), (green, yellower))
    assert det.reason is None and joined == [True, False], det
    monkeypatch.setattr(det_mod, "MERGE_GAP_SAME", det_mod.MERGE_GAP)
    det, joined = clover(*three)
    assert joined == [True, False, False] and math.hypot(det.pixel[0] - 320, det.pixel[1] - 240) > 30, det


def test_faint_first_choice_gets_the_second_look(monkeypatch) -> None:
    """A close-up (2 S square round the centre) of a blue-green lobed rosette on reddish soil
    (bench/other_renderer_plants.py, seed 7 case 39): after the soil white balance only one leaf
    clears G*'s threshold, at 4.4 σ; that faint choice gets the second look, which segments all
    four leaves. Measured: 0.10 S off (0.64 S, on that one leaf's base, without the second look)."""
    import capm_field.detector as det_mod

    orp = bench_module("other_renderer_plants")
    img, t, S, _ = orp.render(np.random.default_rng([7, 39]), "lobed")
    r = np.random.default_rng([7, 39, 3])
    cx, cy = t[0] + r.uniform(-0.1, 0.1) * S, t[1] + r.uniform(-0.1, 0.1) * S
    x0, y0, side = int(round(cx - S)), int(round(cy - S)), int(2 * S)
    assert x0 >= 0 and y0 >= 0 and x0 + side <= img.shape[1] and y0 + side <= img.shape[0]  # a crop of the frame
    k = 640 / side
    crop = cv2.resize(img[y0:y0 + side, x0:x0 + side], (640, 640), interpolation=cv2.INTER_CUBIC)
    truth = np.array([(t[0] - x0) * k, (t[1] - y0) * k])
    det = detect_centre(crop)
    assert det.reason is None and np.hypot(*(np.array(det.pixel) - truth)) < 0.15 * S * k, (det, truth)
    monkeypatch.setattr(det_mod, "FAINT_SIGMA", 0.0)
    det = detect_centre(crop)
    assert det.reason is not None or np.hypot(*(np.array(det.pixel) - truth)) > 0.3 * S * k, (det, truth)


def test_clean_synthetic_rosettes_of_another_renderer() -> None:
    """Flat-coloured rosettes (ellipse leaves from a centre) on flat or lightly noisy soils, as a
    simple independent renderer draws them: found, centre within 0.1 L (median)."""
    rng = np.random.default_rng(3)
    errs = []
    for soil in [(40, 70, 110), (120, 120, 120), (30, 30, 30), (150, 170, 190), (60, 90, 90)]:
        for col in [(40, 160, 60), (30, 110, 100)]:  # (40, 160, 60) has the grey soil's luminance
            for noise in (0, 3):
                img = np.full((720, 1280, 3), soil, np.uint8)
                c = (640 + rng.uniform(-60, 60), 360 + rng.uniform(-60, 60))
                L = rng.uniform(60, 200)
                n = int(rng.integers(3, 9))
                for k in range(n):
                    a = 2 * np.pi * k / n + rng.uniform(-0.3, 0.3)
                    ln = L * rng.uniform(0.6, 1.0)
                    m = (c[0] + 0.5 * ln * math.cos(a), c[1] + 0.5 * ln * math.sin(a))
                    cv2.ellipse(img, (round(m[0]), round(m[1])), (int(ln / 2), int(ln * 0.35 / 2)), math.degrees(a), 0, 360, col, -1, cv2.LINE_AA)
                if noise:
                    img = np.clip(img + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8)
                d = detect_centre(img)
                errs.append(math.inf if d.pixel is None else math.hypot(d.pixel[0] - c[0], d.pixel[1] - c[1]) / L)
    # measured: median 0.05 L, 19 of 20 within 0.15 L (before the leaf-scale votes and the
    # colour flatness check: median 0.21 L and 4 frames "bad_image")
    assert np.median(errs) < 0.1, errs
    assert sum(e < 0.15 for e in errs) >= 18, errs


def test_fan_shaped_grass_tufts_centre_at_the_base() -> None:
    """Dense grass tufts whose blades all lean one way (a fan spreading 25–70°), drawn as tapered
    polygons by OpenCV and blurred: the centre is the common base, not the middle of the blades
    (where Σ distance to the tips lies). Measured: median 0.04 L, 9 of 12 within 0.15 L; before
    `fan_apex` median 0.26 L, 7 of 12."""
    rng = np.random.default_rng(21)
    errs = []
    for k in range(12):
        img = _soil(rng, (720, 1280), colour=(int(rng.integers(60, 140)), int(rng.integers(90, 150)), int(rng.integers(120, 180))))
        base = np.array([640 + rng.uniform(-80, 80), 360 + rng.uniform(-60, 60)])
        L = rng.uniform(120, 220)
        lean, spread = rng.uniform(0, 2 * np.pi), math.radians(rng.uniform(25, 70))
        col = (int(rng.integers(30, 60)), int(rng.integers(120, 170)), int(rng.integers(40, 90)))
        for _ in range(int(rng.integers(8, 16))):
            a = lean + spread * (rng.random() - 0.5)
            ln = L * rng.uniform(0.6, 1.0)
            d = np.array([math.cos(a), math.sin(a)])
            nrm = np.array([-d[1], d[0]])
            w = rng.uniform(3.0, 6.0)  # half-width at the base, px
            tip = base + ln * d
            poly = np.array([base + w * nrm, base + 0.2 * ln * d + w * nrm, tip, base + 0.2 * ln * d - w * nrm, base - w * nrm])
            cv2.fillPoly(img, [np.round(poly * 16).astype(np.int32)], col, cv2.LINE_AA, shift=4)
        det = detect_centre(cv2.GaussianBlur(img, (0, 0), 2.0))
        errs.append(math.inf if det.pixel is None else math.hypot(det.pixel[0] - base[0], det.pixel[1] - base[1]) / L)
    assert np.median(errs) < 0.1, errs
    assert sum(e < 0.15 for e in errs) >= 9, errs


def _trefoil(img: np.ndarray, hub: np.ndarray, a: float, s: float, col) -> None:
    """Three leaflets (ellipses) round `hub`, the middle one pointing along `a`."""
    for da in (-2.0, 0.0, 2.0):
        c = hub + 0.55 * s * np.array([math.cos(a + da), math.sin(a + da)])
        cv2.ellipse(img, (round(c[0]), round(c[1])), (int(0.5 * s), int(0.4 * s)), math.degrees(a + da), 0, 360, col, -1, cv2.LINE_AA)


def test_clover_in_two_halves_is_one_plant() -> None:
    """Two equal trefoils on opposite petioles whose stalks do not show: two near-equal
    candidates just too far apart to be grouped, yet one plant (bench seed 1 case 207). Measured:
    10 of 10 found within 0.11 of the plant's radius; before the merge 8 of 10 "ambiguous"."""
    rng = np.random.default_rng(4)
    errs = []
    for _ in range(10):
        img = _soil(rng, (720, 1280))
        c = np.array([640 + rng.uniform(-50, 50), 360 + rng.uniform(-50, 50)])
        s, a0 = rng.uniform(14, 22), rng.uniform(0, 2 * np.pi)
        P = rng.uniform(1.3, 1.45) * s
        for a in (a0, a0 + np.pi + rng.uniform(-0.3, 0.3)):
            _trefoil(img, c + P * np.array([math.cos(a), math.sin(a)]), a, s, (50, 140, 70))
        det = detect_centre(img)
        assert det.reason is None, det
        errs.append(math.hypot(det.pixel[0] - c[0], det.pixel[1] - c[1]) / (P + s))
    assert max(errs) < 0.2, errs


def test_clover_of_trefoils_on_uneven_hidden_stalks() -> None:
    """4–6 trefoils (ellipse leaflets, middle one pointing away from the centre) at uneven
    angles and stalk lengths, stalks not drawn, blurred: the rays back from the trefoil hubs
    (`compound_centre`) answer 5 of 16 and put 9 of 16 within 0.15 of the plant size (session 3:
    4 and 7, before the ring kernels came from the rounded cache key; 4 without `compound_centre`;
    the geometric median of uneven trefoils is ~0.2–0.3 off)."""
    rng = np.random.default_rng(12)
    errs = []
    for _ in range(16):
        img = _soil(rng, (720, 1280), colour=(int(rng.integers(60, 120)), int(rng.integers(90, 130)), int(rng.integers(120, 170))))
        c = np.array([640 + rng.uniform(-60, 60), 360 + rng.uniform(-60, 60)])
        size = rng.uniform(50, 90)
        n = int(rng.integers(4, 7))
        angs = np.sort(rng.uniform(0, 2 * np.pi, n))
        col = (int(rng.integers(40, 70)), int(rng.integers(120, 160)), int(rng.integers(50, 90)))
        for a in angs:
            s = size * rng.uniform(0.18, 0.3)
            P = max(size * rng.uniform(0.35, 0.95) - s, 0.15 * size)
            _trefoil(img, c + P * np.array([math.cos(a), math.sin(a)]), a + rng.uniform(-0.15, 0.15), s, col)
        det = detect_centre(cv2.GaussianBlur(img, (0, 0), 1.2))
        errs.append(math.inf if det.pixel is None else math.hypot(det.pixel[0] - c[0], det.pixel[1] - c[1]) / size)
    assert sum(e < 0.15 for e in errs) >= 8, errs
    assert max(errs) < 0.5, errs


def test_second_look_does_not_replace_an_ambiguous_choice_by_a_third_object() -> None:
    """Two equal pale plants ("ambiguous") and a small vivid yellow-green disc that only the
    CIELAB second look sees: the answer stays "ambiguous" (it was the disc, confidence 1)."""
    rng = np.random.default_rng(5)
    img = _soil(rng, (720, 1280))
    for cx in (440, 840):
        for a in np.linspace(0, 2 * np.pi, 6, endpoint=False):
            m = (cx + 25 * math.cos(a), 360 + 25 * math.sin(a))
            cv2.ellipse(img, (round(m[0]), round(m[1])), (25, 9), math.degrees(a), 0, 360, (90, 140, 110), -1, cv2.LINE_AA)
    cv2.circle(img, (640, 560), 18, (40, 200, 170), -1, cv2.LINE_AA)
    det = detect_centre(img)
    assert det.reason == "ambiguous", det
    assert det.pixel is not None and math.hypot(det.pixel[0] - 640, det.pixel[1] - 560) > 100, det


def test_plant_outside_the_troi_is_not_reported() -> None:
    """A plant whose centre lies in the ROI margin (outside the TROI itself) is not the weed."""
    rng = np.random.default_rng(8)
    img = _soil(rng)
    c = (320 + 212, 240)  # 1.06 ROI radii from the centre: inside the ×1.15 search margin
    for a in np.linspace(0, 2 * np.pi, 5, endpoint=False):
        cv2.ellipse(img, (int(c[0] + 12 * np.cos(a)), int(c[1] + 12 * np.sin(a))), (12, 6), np.degrees(a), 0, 360, (40, 150, 60), -1, cv2.LINE_AA)
    det = detect_centre(img, Roi.from_ellipse((320, 240), (200, 200)))
    assert det.reason == "no_plant", det


def test_larger_plant_wins_over_small_vivid_one() -> None:
    """A pale weed seedling and a smaller, more saturated distractor in the ROI: the weed wins."""
    rng = np.random.default_rng(6)
    img = _soil(rng)
    big, small = (250, 240), (420, 230)
    for a in (0.3, 0.3 + np.pi):
        end = (int(big[0] + 40 * np.cos(a)), int(big[1] + 40 * np.sin(a)))
        cv2.ellipse(img, ((big[0] + end[0]) // 2, (big[1] + end[1]) // 2), (22, 11), np.degrees(a), 0, 360, (85, 135, 110), -1, cv2.LINE_AA)
    cv2.ellipse(img, small, (10, 6), 20, 0, 360, (30, 170, 40), -1, cv2.LINE_AA)
    det = detect_centre(img, Roi.from_ellipse((320, 240), (200, 200)))
    assert det.reason is None and np.hypot(det.pixel[0] - big[0], det.pixel[1] - big[1]) < 15, det


@pytest.fixture(scope="module")
def large_batch() -> dict:
    """60 views per kind (seed 21) + 60 bare views (seed 22)."""
    n = 60
    errs, missed = [], 0
    for kind in WEED_KINDS:
        e, m, _ = _run(kind, n, seed=21)
        errs += e
        missed += m
    _, _, bare = _run("bare", n, seed=22)
    return dict(total=n * len(WEED_KINDS), errs=errs, missed=missed, bare=bare)


@pytest.mark.slow
def test_target_bare_soil_on_a_large_batch(large_batch) -> None:
    bare = large_batch["bare"]
    assert bare.count("no_plant") >= 0.95 * len(bare), bare


@pytest.mark.slow
def test_target_detection_on_a_large_batch(large_batch) -> None:
    # (met: 3 of 240 missed, session 69, and already with session 68's code; it was a strict xfail, so `-m slow` failed)
    assert large_batch["missed"] <= 0.02 * large_batch["total"]


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="below target: see docs/perception.md (clover centres, wrong seedlings)")
def test_target_centre_error_on_a_large_batch(large_batch) -> None:
    """Wrong centre (> 30 mm) ≤ 1 %, median ≤ 5 mm, p90 ≤ 15 mm."""
    errs = large_batch["errs"]
    assert sum(e > 30.0 for e in errs) <= 0.01 * large_batch["total"]
    assert np.median(errs) <= 5.0 and np.percentile(errs, 90) <= 15.0


@pytest.mark.parametrize(
    "img",
    [
        np.zeros((0, 0, 3), np.uint8),
        np.zeros((720, 1280, 3), np.uint8),
        np.full((720, 1280, 3), 255, np.uint8),
        np.zeros((720, 1280), np.uint8),
        np.zeros((720, 1280, 4), np.uint8),
        np.zeros((720, 1280, 3), np.float32),
        np.zeros((5, 5, 3), np.uint8),
        np.full((100, 100, 3), 128, np.uint8),
        "not an image",
        None,
    ],
)
def test_bad_inputs_never_raise(img) -> None:
    det = detect_centre(img)
    assert isinstance(det, Detection)
    assert det.reason == "bad_image" and det.pixel is None


@pytest.mark.parametrize("shape", [(720, 640), (480, 640), (300, 400), (1080, 1920)])
def test_a_frame_of_noise_is_a_bad_image_not_a_plant(shape) -> None:
    """Uniform RGB noise (a faulty sensor, a corrupted stream): max-pooled greenness made it a
    plant with confidence 0.8 on 18 of 20 frames of 720 × 640; a grey-level coherence test says
    bad_image (white noise ≈ 0.5, scenes ≥ 0.87). A real scene with heavy sensor noise still works."""
    rng = np.random.default_rng(sum(shape))
    assert detect_centre((rng.random((*shape, 3)) * 255).astype(np.uint8)).reason == "bad_image"


@pytest.mark.parametrize("kind", ["jpeg", "gauss40", "binary", "grey"])
def test_other_noise_frames_are_bad_images(kind: str) -> None:
    """JPEG-compressed RGB noise, Gaussian noise of σ = 40 round mid-grey, black-and-white
    noise and grey-level noise: strong noise without structure, "bad_image"."""
    rng = np.random.default_rng(5)
    u = (rng.random((480, 640, 3)) * 255).astype(np.uint8)
    img = {"jpeg": lambda: cv2.imdecode(cv2.imencode(".jpg", u, [cv2.IMWRITE_JPEG_QUALITY, 75])[1], cv2.IMREAD_COLOR),
           "gauss40": lambda: np.clip(128 + rng.normal(0, 40, u.shape), 0, 255).astype(np.uint8),
           "binary": lambda: np.repeat(np.where(rng.random((480, 640, 1)) < 0.5, 0, 255).astype(np.uint8), 3, axis=2),
           "grey": lambda: np.repeat(u[..., :1], 3, axis=2)}[kind]()
    assert detect_centre(img).reason == "bad_image"


@pytest.mark.parametrize("fixture", ["rosette_vga.jpg", "seedling.jpg", "grass_tuft.jpg"])
def test_a_frame_without_colour_is_a_bad_image_not_bare_soil(fixture: str) -> None:
    """A plant photographed by a monochrome camera (or a grey-level file, or a grey JPEG decoded to
    BGR) cannot be judged by its colour: "bad_image", not "no_plant" (which would say there is no
    weed). The same photo in colour is read."""
    img = cv2.imread(str(FIX / fixture))
    assert detect_centre(img).reason is None
    grey = cv2.cvtColor(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR)
    assert detect_centre(grey).reason == "bad_image"
    jpeg = cv2.imdecode(cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, 80])[1], cv2.IMREAD_COLOR)
    assert detect_centre(jpeg).reason == "bad_image"
    # a faint tint is colour: a dull soil photo with a green plant a few levels off grey is read
    tinted = grey.astype(np.int16)
    tinted[..., 1] += 6
    assert detect_centre(np.clip(tinted, 0, 255).astype(np.uint8)).reason != "bad_image"


@pytest.mark.parametrize("soil", [(110, 110, 110), (40, 70, 110)])
@pytest.mark.parametrize("noise", [0, 5, 20])
@pytest.mark.parametrize("leaf_len", [10, 40])
def test_plant_on_a_flat_soil_under_noise_is_read_not_rejected(soil, noise: int, leaf_len: int) -> None:
    """A rosette drawn on a flat soil (a simple renderer) under Gaussian sensor noise: on grey
    soil its leaves are as bright as the soil, so the grey level is noise alone, and a 10-px-leaf
    rosette barely moves the stage-1 grid. Both were "bad_image" (noise, flat frame) while only
    the grey level's coherence and spread were asked; the plant is found within a quarter of its
    size (≥ 8 px). The blank frame: "bad_image" under weak noise, "no_plant" under strong."""
    rng = np.random.default_rng([noise, leaf_len])
    img = np.zeros((720, 1280, 3), np.float32) + np.array(soil, np.float32)
    cx, cy = 610.0, 380.0
    for k in range(5):
        a = 2 * math.pi * k / 5 + 0.4
        cv2.ellipse(img, (int(cx + 0.55 * leaf_len * math.cos(a)), int(cy + 0.55 * leaf_len * math.sin(a))),
                    (leaf_len // 2, max(2, leaf_len // 6)), math.degrees(a), 0, 360, (30, 160, 60), -1, cv2.LINE_AA)
    img = np.clip(img + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8)
    det = detect_centre(img)
    assert det.reason is None, det
    assert math.hypot(det.pixel[0] - cx, det.pixel[1] - cy) < max(0.25 * 2.1 * leaf_len, 8.0), det  # ¼ of the plant
    blank = np.clip(np.zeros((720, 1280, 3)) + soil + rng.normal(0, noise, (720, 1280, 3)), 0, 255).astype(np.uint8)
    assert detect_centre(blank).reason in (("bad_image",) if noise <= 5 else ("no_plant",))


def test_long_green_plants_are_not_straw() -> None:
    """Two narrow cotyledons in a line (elongation 5.4 at full resolution) and a single grass
    blade were scored 0 as straw by their shape alone; green above red in the raw image and
    after the white balance, they are plants. A straw of the same shape is not."""
    rng = np.random.default_rng(3)
    soil = np.clip(cv2.GaussianBlur(rng.normal(0, 10, (720, 1280, 3)), (0, 0), 3) + (50, 80, 120), 0, 255)
    for shape, colour, plant in (("cotyledons", (40, 160, 70), True), ("blade", (40, 150, 80), True), ("blade", (120, 190, 210), False)):
        img = soil.copy()
        if shape == "cotyledons":
            for s in (-1, 1):
                cv2.ellipse(img, (int(640 + s * 33), 360), (31, 11), 0, 0, 360, colour, -1, cv2.LINE_AA)
        else:
            cv2.line(img, (560, 360), (720, 330), colour, 5, cv2.LINE_AA)
        det = detect_centre(np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8),
                            Roi.from_ellipse((640, 350), (150, 150)))
        assert (det.reason is None) == plant, (shape, colour, det)
        if shape == "cotyledons":
            assert math.hypot(det.pixel[0] - 640, det.pixel[1] - 360) < 12, det


def test_two_leaves_whose_stem_does_not_show_meet_in_the_gap() -> None:
    """`pair_gap`: two separate elongated leaves (cotyledons on an unseen hypocotyl) → the middle
    of the gap where they are closest; the pixels' median landed in the bigger leaf, 7–17 px off
    on 130-px seedlings. Lobed or round parts (two clover trefoils) → None. End to end: a
    seedling of two unequal separate cotyledons is found within 6 px of the gap."""
    from capm_field.plant_centre import pair_gap

    m = np.zeros((80, 120), np.uint8)
    cv2.ellipse(m, (38, 40), (26, 10), 10, 0, 360, 1, -1)
    cv2.ellipse(m, (88, 44), (18, 8), 10, 0, 360, 1, -1)
    gap = pair_gap(m.astype(bool))
    assert gap is not None and abs(gap[0] - 64.5) < 3 and abs(gap[1] - 42) < 3, gap
    lobed = np.zeros((80, 120), np.uint8)
    for cx in (30, 85):
        for a in (0, 120, 240):
            cv2.circle(lobed, (int(cx + 9 * math.cos(math.radians(a))), int(40 + 9 * math.sin(math.radians(a)))), 9, 1, -1)
    assert pair_gap(lobed.astype(bool)) is None
    round_ = np.zeros((80, 120), np.uint8)
    cv2.circle(round_, (30, 40), 15, 1, -1)
    cv2.circle(round_, (80, 40), 12, 1, -1)
    assert pair_gap(round_.astype(bool)) is None
    img = np.zeros((720, 1280, 3), np.float32) + (40, 70, 110)
    cv2.ellipse(img, (598, 352), (33, 15), 10, 0, 360, (30, 160, 60), -1, cv2.LINE_AA)
    cv2.ellipse(img, (672, 365), (24, 13), 10, 0, 360, (30, 160, 60), -1, cv2.LINE_AA)
    img = np.clip(img + np.random.default_rng(0).normal(0, 2, img.shape), 0, 255).astype(np.uint8)
    dbg: dict = {}
    det = detect_centre(img, debug=dbg)
    assert det.reason is None and dbg["method"] == "pair_gap", (det, dbg.get("method"))
    assert math.hypot(det.pixel[0] - 639.5, det.pixel[1] - 359.3) < 5, det  # between the tips (630.5, 357.7), (648.4, 360.8)


def test_heavy_sensor_noise_on_a_scene_is_still_read() -> None:
    """Gaussian noise σ = 20 grey levels on a bench rosette view: still a scene, still the weed."""
    case = make_case(11, 0, CAM, 0.1, bare=False)  # index 0: a rosette
    img = case.scene.render(case.T, CAM)
    noisy = np.clip(img + np.random.default_rng(1).normal(0, 20, img.shape), 0, 255).astype(np.uint8)
    roi = roi_from_troi(CAM, case.T, case.troi_centre, case.troi_radius)
    clean, det = detect_centre(img, roi), detect_centre(noisy, roi)
    assert clean.reason is None and det.reason is None, det
    g = ground_centre(CAM, case.T, det)
    assert np.linalg.norm(g - case.scene.weeds[0].centre) < 0.015


def test_expected_bad_input_is_not_logged_as_a_failure(caplog) -> None:
    """Bad input is answered by the input checks (no traceback in the log); only a failure inside
    the detector goes to the log, with its traceback, before "bad_image" is answered."""
    import capm_field.detector as det_mod

    with caplog.at_level("ERROR", logger="capm_field.detector"):
        for img in (np.zeros((480, 640), np.uint8), np.zeros((480, 640, 3), np.float32), "not an image", None,
                    np.zeros((480, 640, 3), np.uint8)):
            assert detect_centre(img).reason == "bad_image"
    assert not caplog.records, [r.getMessage() for r in caplog.records]

    def broken(*a, **k):
        raise RuntimeError("bug")

    img = np.zeros((480, 640, 3), np.uint8)  # a scene-like image (a gradient: not flat, not noise, not grey)
    img[:] = np.linspace(60, 160, 640, dtype=np.uint8)[None, :, None]
    img[..., 2] += 20  # a brownish tint: a frame without colour is rejected before any detection
    orig = det_mod._detect
    det_mod._detect = broken
    try:
        with caplog.at_level("ERROR", logger="capm_field.detector"):
            assert detect_centre(img).reason == "bad_image"
    finally:
        det_mod._detect = orig
    assert len(caplog.records) == 1 and caplog.records[0].exc_info is not None


def test_detection_holds_blas_to_one_thread_and_restores_it(monkeypatch) -> None:
    """The detector's budget is one core: during a detection every loaded BLAS library runs one
    thread (OpenBLAS would split the larger products between threads), and the process's own
    setting (two threads here) is back afterwards, also when the detection fails inside."""
    from threadpoolctl import ThreadpoolController, threadpool_limits

    import capm_field.detector as det_mod

    seen: list[list[int]] = []
    orig = det_mod.search_window

    def spy(*a, **k):
        seen.append([lib["num_threads"] for lib in ThreadpoolController().select(user_api="blas").info()])
        return orig(*a, **k)

    case = make_case(0, 1, CAM, TaskConfig().delta, False)
    img = case.scene.render(case.T, CAM)
    monkeypatch.setattr(det_mod, "search_window", spy)
    with threadpool_limits(2, user_api="blas"):
        assert detect_centre(img).reason is None
        monkeypatch.setattr(det_mod, "_looks", lambda *a, **k: 1 / 0)
        assert detect_centre(img).reason == "bad_image"
        after = [lib["num_threads"] for lib in ThreadpoolController().select(user_api="blas").info()]
    assert len(seen) == 2 and all(n == 1 for calls in seen for n in calls) and seen[0], seen
    assert after and all(n == 2 for n in after), after


def test_overlapping_detections_share_one_blas_limit() -> None:
    """Detections in two threads that overlap (A starts, B starts, A ends, B ends): BLAS stays at
    one thread until the last ends, then gets the process's setting back (a limiter per call let A
    restore two threads under B, and B then left the process at one)."""
    from threadpoolctl import ThreadpoolController, threadpool_limits

    import capm_field.detector as det_mod

    def threads() -> set[int]:
        return {lib["num_threads"] for lib in ThreadpoolController().select(user_api="blas").info()}

    limit = det_mod._one_blas_thread
    with threadpool_limits(2, user_api="blas"):
        limit.__enter__()  # A
        limit.__enter__()  # B
        limit.__exit__(None, None, None)  # A ends
        during = threads()
        limit.__exit__(None, None, None)  # B ends
        after = threads()
    assert during == {1} and after == {2}, (during, after)


def test_bad_roi_never_raises() -> None:
    img = cv2.imread(str(FIX / "rosette_vga.jpg"))  # a plant: only the roi can make it bad_image
    assert detect_centre(img).reason is None
    for roi in (np.eye(3), "x", ((10, 10), (-5, 3), 0), np.full((3, 3), np.nan), ((np.inf, 1), (1, 1), 0),
                ((300, 200), (50, 50), float("nan")), [[1, 0], [0, 1]]):
        assert detect_centre(img, roi).reason == "bad_image", roi


def test_conic_roi_as_nested_lists() -> None:
    img = cv2.imread(str(FIX / "rosette_vga.jpg"))
    C = Roi.from_ellipse((376, 195), (150, 120), 10).conic
    assert detect_centre(img, C.tolist()) == detect_centre(img, C)


def test_degenerate_or_huge_roi_is_answered_without_a_traceback(caplog) -> None:
    """A conic without interior is bad input (no logged failure); an ellipse holding the whole
    frame, however large, is the same as no ROI; a huge one off to a side still works."""
    img = cv2.imread(str(FIX / "rosette_vga.jpg"))
    with caplog.at_level("ERROR", logger="capm_field.detector"):
        assert detect_centre(img, ((376, 195), (0, 0), 0)).reason == "bad_image"
        assert detect_centre(img, np.diag([1.0, 1.0, 1.0])).reason == "bad_image"
        # a Roi built directly (not by from_conic / roi_from_troi) with a ground map that is no map
        conic = Roi.from_ellipse((376, 195), (150, 150)).conic
        rank2 = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
        for ground in (np.zeros((3, 3)), rank2, np.eye(2), np.full((3, 3), np.nan)):
            with pytest.raises(ValueError):
                Roi(conic, ground)
        whole = detect_centre(img)
        for roi in (((376, 195), (1e9, 1e9), 0), ((320, 240), (4000, 3000), 10.0)):
            assert detect_centre(img, roi).pixel == whole.pixel
        side = detect_centre(img, ((-1e9 + 560, 195), (2e9, 4e8), 0))  # holds x ≤ 560: the plant
        assert side.reason is None and np.hypot(side.pixel[0] - whole.pixel[0], side.pixel[1] - whole.pixel[1]) < 3
    assert not caplog.records, [r.getMessage() for r in caplog.records]


def test_roi_representations_agree() -> None:
    r = Roi.from_ellipse((300.0, 200.0), (120.0, 60.0), 30.0)
    (cu, cv_), (w, h), ang = r.ellipse()
    r2 = Roi.from_conic(-3.0 * r.conic)  # any scale and sign of the conic
    assert np.allclose([cu, cv_, w, h], [300, 200, 240, 120])
    assert np.allclose(r2.conic, r.conic / np.abs(r.conic).max() * np.abs(r2.conic).max()) or r2.contains(np.array([[300.0, 200.0]]))[0]
    pts = np.array([[300.0, 200.0], [300 + 119 * np.cos(np.radians(30)), 200 + 119 * np.sin(np.radians(30))], [300.0, 330.0]])
    assert list(r.contains(pts)) == [True, True, False]
    assert list(r2.contains(pts)) == [True, True, False]


@settings(max_examples=60, deadline=None)
@given(cu=st.floats(-500.0, 2000.0), cv_=st.floats(-500.0, 2000.0), a=st.floats(0.5, 5000.0), ratio=st.floats(0.05, 1.0),
       ang=st.floats(-360.0, 360.0))
@example(cu=0.0, cv_=1665.0, a=0.5, ratio=0.05078125, ang=0.0)  # the conic test of `contains` failed here
@example(cu=1789.0, cv_=379.0, a=0.5, ratio=0.0546875, ang=124.0)  # the area from pixel coordinates: cancellation
def test_roi_rim_lies_on_the_ellipse(cu, cv_, a, ratio, ang) -> None:
    """`Roi.rim` (the ROI drawn in review): every point on the ellipse's boundary, going once round it."""
    r = Roi.from_ellipse((cu, cv_), (a, a * ratio), ang)
    rim = r.rim(72)
    assert rim.shape == (72, 2)
    # on the boundary, in the ellipse's own frame (not by `contains`: its conic, 4e9 for a 0.025 px axis
    # 1 665 px out, loses the 1e-6 to cancellation)
    t = math.radians(ang)
    d = rim - (cu, cv_)
    rho = np.hypot((d[:, 0] * math.cos(t) + d[:, 1] * math.sin(t)) / a, (-d[:, 0] * math.sin(t) + d[:, 1] * math.cos(t)) / (a * ratio))
    assert np.allclose(rho, 1.0, atol=1e-6), rho
    # once round, evenly in the parameter: the polygon's area is that of the inscribed 72-gon (the
    # shoelace on offsets from the centre: from pixel coordinates 1 789 px out, a 0.04 px² area is
    # lost to cancellation at 1e-6)
    area = 0.5 * abs(np.dot(d[:, 0], np.roll(d[:, 1], -1)) - np.dot(d[:, 1], np.roll(d[:, 0], -1)))
    assert area == pytest.approx(36 * math.sin(2 * math.pi / 72) * a * a * ratio, rel=1e-6)


@settings(max_examples=40, deadline=None)
@given(cu=st.floats(160.0, 480.0), cv_=st.floats(160.0, 320.0), a=st.floats(3.0, 150.0), ratio=st.floats(0.3, 1.0),
       ang=st.floats(0.0, 180.0))
@example(cu=160.0, cv_=160.0, a=7.1875, ratio=0.5, ang=12.0)  # 4.7° off: failed the former flat 4° bound
def test_mask_roi_is_the_ellipse_it_holds(cu, cv_, a, ratio, ang) -> None:
    """A filled ellipse rasterised as a mask gives that ellipse back (`Roi.from_mask`). OpenCV draws
    it as a polygon on whole pixels: over 3 000 random ellipses the centre was within 0.3 px, each
    full axis within 1.5 px and the long axis within 2.5° (when a − b > 3 px). A small ellipse's
    axis is held to 4° or to the turn of a 1.5 px error at its tip, whichever is larger (a = 7.2 px,
    b = 3.6 px came back 4.7° off in a random draw; 8 000 ellipses with a = 6–14 px: ≤ 6°, a·d ≤ 53)."""
    b = max(a * ratio, 3.0)
    m = np.zeros((480, 640), np.uint8)
    S = 256  # OpenCV's fixed-point drawing: sub-pixel centre and axes
    cv2.ellipse(m, (round(cu * S), round(cv_ * S)), (round(a * S), round(b * S)), ang, 0, 360, 1, -1, cv2.LINE_8, 8)
    (u, v), (w, h), ang2 = as_roi(m, m.shape).ellipse()
    assert np.hypot(u - cu, v - cv_) < 0.4
    assert abs(max(w, h) - 2 * a) < 2.0 and abs(min(w, h) - 2 * b) < 2.0, ((w, h), (a, b))
    if a - b > 3:  # the long axis has a direction
        d = abs(((ang2 if w >= h else ang2 + 90) - ang + 90) % 180 - 90)
        assert d < max(4.0, math.degrees(math.atan(1.5 / a))), (ang2, ang, a, b)


def test_circle_roi_forms_are_the_ellipse() -> None:
    """A circle ROI as OpenCV gives one, ((cu, cv), r) or (cu, cv, r), is that circle's ellipse."""
    img = cv2.imread(str(FIX / "rosette_vga.jpg"))
    want = detect_centre(img, ((376.0, 195.0), (300.0, 300.0), 0.0))
    assert want.reason is None
    for roi in (((376.0, 195.0), 150.0), (376.0, 195.0, 150.0), np.array([376.0, 195.0, 150.0]), [[376, 195], 150]):
        assert np.array_equal(as_roi(roi).conic, Roi.from_ellipse((376.0, 195.0), (150.0, 150.0)).conic), roi
        assert detect_centre(img, roi) == want, roi
    for bad in (((376.0, 195.0), -1.0), (376.0, 195.0), (376.0, 195.0, 150.0, 1.0), ((1.0, 2.0, 3.0), 4.0)):
        assert detect_centre(img, bad).reason == "bad_image", bad


def test_mask_roi_is_answered_like_its_ellipse() -> None:
    """A mask of the ROI (a foreign caller's rasterised TROI) is answered like its ellipse; a mask of
    the whole image is no ROI; a mask of another size, empty, a line or NaN is bad input."""
    img = cv2.imread(str(FIX / "rosette_vga.jpg"))
    truth = json.loads((FIX / "truth.json").read_text())["rosette_vga.jpg"]
    H, W = img.shape[:2]
    ell = ((376.0, 195.0), (300.0, 240.0), 10.0)
    m = np.zeros((H, W), np.uint8)
    cv2.ellipse(m, ell, 255, -1)
    a, b = detect_centre(img, ell), detect_centre(img, m)
    assert a.reason is None and b.reason is None
    # the mask's ellipse is the drawn one to ~1 px, which moves the detector's grid: measured 6 px (the
    # ellipse) and 7 px (its mask) from the crown, 8 px apart, on a plant of 168 px
    for d in (a, b):
        assert np.hypot(d.pixel[0] - truth["centre"][0], d.pixel[1] - truth["centre"][1]) < 0.1 * truth["plant_size_px"], d
    assert np.hypot(a.pixel[0] - b.pixel[0], a.pixel[1] - b.pixel[1]) < 0.1 * truth["plant_size_px"], (a, b)
    assert detect_centre(img, m.astype(bool)).pixel == b.pixel and detect_centre(img, m[:, :, None]).pixel == b.pixel
    assert detect_centre(img, np.ones((H, W), bool)) == detect_centre(img)
    line = np.zeros((H, W), np.uint8)
    line[200, 100:500] = 1
    for bad in (m[:, :-1], np.zeros((H, W), np.uint8), line, np.where(m > 0, np.nan, 0.0), np.zeros((H, W, 3), np.uint8)):
        assert detect_centre(img, bad).reason == "bad_image"
    # a mask picks the plant inside it, as an ellipse does (two plants in the frame)
    rng = np.random.default_rng(3)
    two = np.clip(rng.normal(0, 5, (480, 640, 3)) + (70, 95, 130), 0, 255).astype(np.uint8)
    for c in ((150, 240), (480, 240)):
        for t in np.linspace(0, 2 * np.pi, 5, endpoint=False):
            cv2.line(two, c, (int(c[0] + 60 * np.cos(t)), int(c[1] + 60 * np.sin(t))), (40, 150, 60), 12, cv2.LINE_AA)
    for c in ((150, 240), (480, 240)):
        disc = np.zeros((480, 640), bool)
        disc[np.hypot(*np.mgrid[:480, :640][::-1] - np.array(c)[:, None, None]) <= 110] = True
        d = detect_centre(two, disc)
        assert d.reason is None and abs(d.pixel[0] - c[0]) < 10 and abs(d.pixel[1] - c[1]) < 10, (c, d)


@settings(max_examples=40, deadline=None)
@given(tilt=st.floats(0.0, 40.0), yaw=st.floats(-math.pi, math.pi), h=st.floats(0.4, 1.5),
       u=st.floats(0.1, 0.9), v=st.floats(0.1, 0.9))
def test_roi_ground_map_gives_troi_distance_and_relative_pixel_area(tilt, yaw, h, u, v) -> None:
    """`Roi.on_ground` from `roi_from_troi`: the distance from X_w in TROI radii and the ground area
    of a pixel relative to the TROI centre's, the same as through `pixel_to_ground`."""
    t = math.radians(tilt)
    z = np.array([math.sin(t) * math.cos(yaw), math.sin(t) * math.sin(yaw), -math.cos(t)])
    T = pose_from_axis(np.array([0.1, -0.2, h]), z, 0.3)
    X, r = np.array([0.1, -0.2]) + h * math.tan(t) * z[:2] / max(math.hypot(*z[:2]), 1e-9), 0.2  # under the optical axis
    roi = roi_from_troi(CAM, T, X, r)
    p = np.array([u * CAM.width, v * CAM.height])

    def pixel_area(q: np.ndarray) -> float:
        g = CAM.pixel_to_ground(T, np.array([q, q + (0.5, 0.0), q + (0.0, 0.5)]))
        a, b = g[1] - g[0], g[2] - g[0]
        return abs(a[0] * b[1] - a[1] * b[0])

    d, area = roi.on_ground(p)
    g = CAM.pixel_to_ground(T, p[None])[0]
    assert d == pytest.approx(np.linalg.norm(g - X) / r, rel=1e-6)
    c = CAM.ground_to_pixel(T, X[None])[0]
    assert area == pytest.approx(pixel_area(p) / pixel_area(c), rel=1e-3)
    assert Roi.from_conic(roi.conic).on_ground(p) is None  # a bare conic has no ground


def test_plant_larger_on_the_ground_wins_under_an_oblique_view() -> None:
    """Two rosettes at the same ground distance from X_w, the far one 1.2× larger on the ground
    but smaller in the oblique image: with the camera's ground map (`roi_from_troi`) the far one
    is chosen; with the same ROI as a bare conic (pixel areas) the near one is."""
    rng = np.random.default_rng(2)
    tex = np.clip(rng.normal(0, 6, (800, 800, 3)) + (70, 95, 130), 0, 255).astype(np.uint8)  # 1 mm a texel
    near, far = (400, 280), (400, 520)
    for c, size in ((near, 30), (far, 36)):
        for a in np.linspace(0, 2 * np.pi, 5, endpoint=False):
            m = (c[0] + 0.5 * size * math.cos(a), c[1] + 0.5 * size * math.sin(a))
            cv2.ellipse(tex, (round(m[0]), round(m[1])), (round(0.5 * size), round(0.2 * size)), math.degrees(a),
                        0, 360, (40, 150, 60), -1, cv2.LINE_AA)
    A = np.array([[1e-3, 0, -0.4], [0, 1e-3, -0.4], [0, 0, 1]])  # texel → field point
    t = math.radians(35)
    T = pose_from_axis(np.array([0.0, -0.7 * math.tan(t), 0.7]), np.array([0.0, math.sin(t), -math.cos(t)]), 0.0)
    img = cv2.warpPerspective(tex, CAM.homography(T) @ A, (CAM.width, CAM.height), flags=cv2.INTER_AREA)
    roi = roi_from_troi(CAM, T, (0.0, 0.0), 0.25)
    pn, pf = (CAM.ground_to_pixel(T, np.array([[(q[0] - 400) * 1e-3, (q[1] - 400) * 1e-3]]))[0] for q in (near, far))
    det = detect_centre(img, roi)
    assert det.reason is None and np.hypot(*(np.array(det.pixel) - pf)) < 15, (det, pf)
    det = detect_centre(img, Roi.from_conic(roi.conic))
    assert np.hypot(*(np.array(det.pixel) - pn)) < 15, (det, pn)


def test_roi_restricts_search() -> None:
    """Two plants: the ROI decides which one is reported."""
    rng = np.random.default_rng(3)
    img = np.clip(rng.normal(0, 5, (480, 640, 3)) + (70, 95, 130), 0, 255).astype(np.uint8)
    for c in ((150, 240), (480, 240)):
        for a in np.linspace(0, 2 * np.pi, 5, endpoint=False):
            end = (int(c[0] + 60 * np.cos(a)), int(c[1] + 60 * np.sin(a)))
            cv2.line(img, c, end, (40, 150, 60), 12, cv2.LINE_AA)
    d = detect_centre(img, Roi.from_ellipse((480, 240), (110, 110)))
    assert d.reason is None and abs(d.pixel[0] - 480) < 10 and abs(d.pixel[1] - 240) < 10


def test_hand_made_photos_of_various_sizes() -> None:
    truth = json.loads((FIX / "truth.json").read_text())
    assert len(truth) >= 4
    for name, t in truth.items():
        img = cv2.imread(str(FIX / name))
        assert img is not None and (FIX / name).stat().st_size < 50_000
        det = detect_centre(img)
        assert det.reason is None, name
        err = np.linalg.norm(np.asarray(det.pixel) - t["centre"]) / t["plant_size_px"]
        # measured (session 50): rosette_small 0.32 (a half-disc of leaves fanning from a broad
        # base: `wide_fan`'s apex; 0.24 before it, by the tree median, 0.43 with the fine votes), rosette_vga 0.07,
        # rosette_big 0.06, grass_tuft 0.02, seedling 0.02
        assert err < 0.4, (name, err)


def test_petiole_centre_ignores_a_blade_that_carries_no_leaf() -> None:
    """Stalks A (long) and B (short) meet at the centre C; a straight blade grouped with the
    plant but far from every leaf lies on a line through the far end of A. Blade + A outweigh
    A + B, so without the "a stalk carries a leaf" rule the answer is that far end, 33 px off
    (bench seed 1 case 71: a clover 51 mm off → 5.5 mm)."""
    from capm_field.plant_centre import petiole_centre

    m = np.zeros((100, 110), np.uint8)
    cv2.circle(m, (25, 63), 10, 1, -1)  # a leaf next to the centre
    cv2.line(m, (40, 50), (70, 50), 1, 1)  # stalk A ...
    cv2.circle(m, (78, 50), 8, 1, -1)  # ... to its leaf
    cv2.line(m, (40, 46), (40, 34), 1, 1)  # stalk B ...
    cv2.circle(m, (40, 26), 8, 1, -1)  # ... to its leaf
    d = np.array([0.5, -math.sqrt(3) / 2])  # the blade, on a line through (74, 50)
    p0, p1 = np.array([74.0, 50.0]) + 24 * d, np.array([74.0, 50.0]) + 42 * d
    cv2.line(m, tuple(int(round(v)) for v in p0), tuple(int(round(v)) for v in p1), 1, 2)
    plant = m > 0
    X = petiole_centre(plant, np.where(plant, 0.3, 0.0).astype(np.float32), 0.0, 0.1)
    assert X is not None and math.hypot(X[0] - 40, X[1] - 50) < 2.0, X


def test_petiole_centre_meets_stalks_seen_only_as_ridges() -> None:
    """Three trefoils (discs) on stalks that are faint index ridges only, not in the mask, meet at
    C, 32 px from every leaf (> 0.12 × the plant size, where a meeting far from the plant used to
    be refused): the meeting is near the stalks, so it is the centre (bench seed 6 case 67: a
    clover 37.8 mm off → 0.5 mm)."""
    from capm_field.plant_centre import petiole_centre

    m = np.zeros((120, 120), np.uint8)
    vi = np.zeros((120, 120), np.float32)
    C = np.array([60.0, 62.0])
    for a in (90, 210, 330):
        d = np.array([math.cos(math.radians(a)), -math.sin(math.radians(a))])
        cv2.circle(m, tuple(int(round(v)) for v in C + 44 * d), 10, 1, -1)
        line = np.zeros_like(vi)
        cv2.line(line, tuple(int(round(v)) for v in C + 3 * d), tuple(int(round(v)) for v in C + 36 * d), 1.0, 1)
        vi = np.maximum(vi, 0.06 * line)  # above soil + 0.3 (thr − soil), below thr
    plant = m > 0
    ys, xs = np.nonzero(plant)
    off = cv2.distanceTransform((~plant).astype(np.uint8), cv2.DIST_L2, 3)[int(C[1]), int(C[0])]
    assert off > 0.12 * math.hypot(np.ptp(xs) + 1, np.ptp(ys) + 1)
    X = petiole_centre(plant, np.where(plant, 0.3, vi).astype(np.float32), 0.0, 0.1)
    assert X is not None and math.hypot(*(X - C)) < 2.0, X


def test_petiole_centre_ignores_a_ridge_along_a_leaf_rim(monkeypatch) -> None:
    """A ridge 3 px outside a leaf's straight edge is no stalk: with the one real stalk it would
    make a meeting at (72, 27), where nothing starts. With the rim rule there is one stalk, so no
    answer (the tree median decides)."""
    import capm_field.plant_centre as pc

    m = np.zeros((100, 100), np.uint8)
    cv2.rectangle(m, (20, 30), (60, 60), 1, -1)  # a broad leaf with a straight edge
    cv2.line(m, (72, 35), (72, 62), 1, 1)  # a stalk ...
    cv2.circle(m, (72, 70), 8, 1, -1)  # ... to its leaf
    cv2.circle(m, (82, 14), 6, 1, -1)  # another leaf
    plant = m > 0
    vi = np.where(plant, 0.3, 0.0).astype(np.float32)
    vi[27, 22:59] = 0.06  # the ridge along the edge
    assert pc.petiole_centre(plant, vi, 0.0, 0.1) is None
    monkeypatch.setattr(pc, "PET_RIM", -1.0)
    X = pc.petiole_centre(plant, vi, 0.0, 0.1)
    assert X is not None and math.hypot(X[0] - 72, X[1] - 27) < 2.0, X


def test_compound_centre_declines_plants_without_three_lobed_hubs() -> None:
    """A single disc, a lone blade and a tiny mask are not compound-leaved plants: None."""
    from capm_field.compound_leaf import compound_centre

    for draw in (lambda m: cv2.circle(m, (40, 40), 25, 1, -1), lambda m: cv2.line(m, (10, 10), (70, 60), 1, 3),
                 lambda m: cv2.circle(m, (40, 40), 2, 1, -1)):
        m = np.zeros((80, 80), np.uint8)
        draw(m)
        plant = m > 0
        vi = np.where(plant, 0.2, -0.03).astype(np.float32)
        assert compound_centre(plant, vi, -0.03) is None


def test_compound_leaves_are_told_from_simple_leaves_and_blades() -> None:
    """`has_compound_leaves` (trefoils whose rays back did not meet → the geometric median, not
    the tree median): true for 4–6 trefoils round a centre and for two on opposite stalks,
    false for a rosette of long simple leaves, a fan of grass blades and a disc, on an ~80 px
    stage-2 grid."""
    from capm_field.compound_leaf import compound_hubs, has_compound_leaves

    def verdict(draw) -> bool:
        m = np.zeros((100, 100), np.uint8)
        draw(m)
        m = cv2.GaussianBlur(m.astype(np.float32), (0, 0), 0.8)
        plant = m > 0.5
        vi = np.where(plant, 0.05 + 0.15 * m, -0.03).astype(np.float32)
        ys, xs = np.nonzero(plant)
        size = math.hypot(np.ptp(xs) + 1, np.ptp(ys) + 1)
        return has_compound_leaves(compound_hubs(plant, vi, -0.03, size))

    rng = np.random.default_rng(3)
    c = np.array([50.0, 50.0])
    for _ in range(6):
        n = int(rng.integers(4, 7))
        angs = np.sort(rng.uniform(0, 2 * np.pi, n))
        s = rng.uniform(11, 14)

        def clover(m, angs=angs, s=s):
            for a in angs:
                _trefoil(m, c + rng.uniform(20, 30) * np.array([math.cos(a), math.sin(a)]), a, s, 1)

        assert verdict(clover), angs

    def two_trefoils(m):
        for a in (0.3, 0.3 + np.pi):
            _trefoil(m, c + 26 * np.array([math.cos(a), math.sin(a)]), a, 13, 1)

    assert verdict(two_trefoils)

    def rosette(m):
        for a in np.linspace(0, 2 * np.pi, 7, endpoint=False) + 0.2:
            tip = c + 40 * np.array([math.cos(a), math.sin(a)])
            mid = (c + tip) / 2
            cv2.ellipse(m, (round(mid[0]), round(mid[1])), (20, 6), math.degrees(a), 0, 360, 1, -1)

    def grass(m):
        for a in np.linspace(-0.8, 0.8, 9):
            cv2.line(m, (50, 90), (round(50 + 70 * math.sin(a)), round(90 - 70 * math.cos(a))), 1, 2)

    for name, draw in (("rosette", rosette), ("grass", grass), ("disc", lambda m: cv2.circle(m, (50, 50), 30, 1, -1))):
        assert not verdict(draw), name


def test_pale_seedling_is_preferred_to_a_smaller_vivid_speck() -> None:
    """A yellow-green seedling (G ≈ R: only the CIELAB second look segments it) and a smaller
    vivid green pair of specks that the first look sees: the seedling, the larger plant, is the
    answer (it was the speck before the second look also ran after a small first choice)."""
    import capm_field.detector as det_mod

    rng = np.random.default_rng(9)
    img = _soil(rng, (720, 1280), colour=(95, 110, 115))
    c = np.array([560.0, 330.0])
    _yellow_green_seedling(img, c)
    speck = np.array([764.0, 418.0])
    for dx in (-4, 4):
        cv2.ellipse(img, (int(speck[0]) + dx, int(speck[1]) - dx // 2), (9, 4), 30, 0, 360, (40, 160, 60), -1, cv2.LINE_AA)
    roi = Roi.from_ellipse((640, 360), (300, 300))
    first = det_mod._detect(img, roi)  # the first look alone: the speck
    assert first.reason is None and np.hypot(*(np.array(first.pixel) - speck)) < 10, first
    det = detect_centre(img, roi)
    assert det.reason is None and np.hypot(*(np.array(det.pixel) - c)) < 8, det
    # with debug: the same answer, and the second look's components follow the first look's
    dbg: dict = {}
    assert detect_centre(img, roi, debug=dbg) == det
    looks = [comp["vivid"] for comp in dbg["comps"]]
    assert looks == sorted(looks) and looks[0] is False and looks[-1] is True, looks
    assert dbg["method"] and dbg["mask_full"].shape == img.shape[:2]


def _lens_rosette(img: np.ndarray, rng: np.random.Generator, c: np.ndarray, L: float, col) -> None:
    """3–8 lens-shaped leaves (pointed at both ends) from `c`, uneven gaps (Dirichlet), the
    longest L, longest drawn first so shorter ones overlap it; no young leaves at the centre."""
    n = int(rng.integers(3, 9))
    angs = rng.uniform(0, 2 * np.pi) + np.cumsum(rng.dirichlet(np.full(n, 1.5)) * 2 * np.pi)
    lens = np.sort(L * rng.uniform(0.45, 1.0, n))[::-1]
    lens[0] = L
    for a, ln in zip(angs, lens):
        _lens_leaf(img, c, a, ln, rng.uniform(0.12, 0.22), col)


def _lens_leaf(img: np.ndarray, c: np.ndarray, a: float, ln: float, width: float, col) -> None:
    """One lens-shaped leaf from `c` along angle `a`, length `ln`, half-width ≤ width × ln."""
    t = np.linspace(0, 1, 30)
    hw = ln * width * np.sin(np.pi * t**0.8)
    pts = np.r_[np.c_[t * ln, hw], np.c_[t * ln, -hw][::-1]]
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    cv2.fillPoly(img, [np.round((pts @ R.T + c) * 16).astype(np.int32)], col, cv2.LINE_AA, shift=4)


def test_uneven_lens_rosettes_centre_where_leaf_axes_meet() -> None:
    """Rosettes of pointed, uneven leaves drawn by OpenCV (another renderer than the bench's, no
    young leaves marking the centre): the leaves' broad edges vote everywhere, and the middle of
    the mask is pulled towards the biggest leaves; the axes traced back from the tips meet at the
    centre (`leaf_axes`). Measured: 13 of 16 within 0.1 L, median 0.05 L; without `tip_axes`
    (the geometric median) 5 of 16, median 0.21 L."""
    rng = np.random.default_rng(12)
    errs = []
    for _ in range(16):
        img = _soil(rng, (720, 1280), colour=(int(rng.integers(50, 90)), int(rng.integers(90, 130)), int(rng.integers(120, 170))))
        c = np.array([640 + rng.uniform(-100, 100), 360 + rng.uniform(-60, 60)])
        L = rng.uniform(70, 200)
        _lens_rosette(img, rng, c, L, (int(rng.integers(30, 60)), int(rng.integers(120, 170)), int(rng.integers(40, 90))))
        det = detect_centre(cv2.GaussianBlur(img, (0, 0), 1.0))
        errs.append(math.inf if det.pixel is None else math.hypot(det.pixel[0] - c[0], det.pixel[1] - c[1]) / L)
    assert sum(e < 0.1 for e in errs) >= 11, np.round(errs, 3)
    assert np.median(errs) < 0.07, np.round(errs, 3)


def test_tip_axes_centre_on_clean_masks() -> None:
    """`leaf_axes.tip_axes_centre` on 80 px masks of uneven lens rosettes finds the centre within
    0.1 L for most; it declines a pair of opposite leaves (axes parallel: no meeting point) and
    one trefoil hub among several (most leaflet tips do not point at it)."""
    from capm_field import leaf_axes
    from capm_field.plant_centre import geometric_median

    rng = np.random.default_rng(5)
    errs, errs_gm = [], []
    for _ in range(30):
        m = np.zeros((120, 120), np.uint8)
        c = np.array([60 + rng.uniform(-8, 8), 60 + rng.uniform(-8, 8)])
        _lens_rosette(m, rng, c, 40.0, 1)
        plant = m > 0
        ys, xs = np.nonzero(plant)
        g = geometric_median(np.c_[xs, ys].astype(float))
        r = leaf_axes.tip_axes_centre(plant, g)
        errs.append(math.inf if r is None else float(np.linalg.norm(r[0] - c)) / 40)
        errs_gm.append(float(np.linalg.norm(g - c)) / 40)
    assert sum(e < 0.1 for e in errs) >= 22, np.round(errs, 3)  # measured 25 of 30
    assert sum(e < 0.1 for e in errs_gm) <= 12, np.round(errs_gm, 3)  # the test can tell (measured 9)
    # two opposite leaves: the axes are parallel
    m = np.zeros((120, 120), np.uint8)
    for a in (0.3, 0.3 + np.pi):
        cv2.ellipse(m, (round(60 + 20 * math.cos(a)), round(60 + 20 * math.sin(a))), (20, 8), math.degrees(a), 0, 360, 1, -1)
    ys, xs = np.nonzero(m)
    assert leaf_axes.tip_axes_centre(m > 0, geometric_median(np.c_[xs, ys].astype(float))) is None
    # four trefoils round an empty centre: each hub gathers only its own three leaflet tips
    m = np.zeros((160, 160), np.uint8)
    for a in (0.2, 1.8, 3.3, 4.6):
        _trefoil(m, np.array([80.0, 80.0]) + 45 * np.array([math.cos(a), math.sin(a)]), a, 14, 1)
    ys, xs = np.nonzero(m)
    r = leaf_axes.tip_axes_centre(m > 0, geometric_median(np.c_[xs, ys].astype(float)))
    assert r is None or np.linalg.norm(r[0] - 80) < 10, r


def test_green_plant_on_yellow_sand_is_found() -> None:
    """A dark green rosette on yellow sand (B ≪ G ≈ R): the soil white balance must not turn the
    sand grey and the leaves blue-grey (gains bounded to 0.8–1.25; with 0.6–1.6 "no_plant")."""
    rng = np.random.default_rng(2)
    img = _soil(rng, (720, 1280), colour=(84, 160, 165))
    c = np.array([600.0, 380.0])
    _lens_rosette(img, rng, c, 140.0, (70, 110, 50))
    det = detect_centre(cv2.GaussianBlur(img, (0, 0), 1.0))
    assert det.reason is None, det
    assert math.hypot(det.pixel[0] - c[0], det.pixel[1] - c[1]) < 0.25 * 140, det


def test_dull_plant_filling_the_frame_is_found() -> None:
    """Dull green rosettes (G − R 10–30) covering 11–15 % of a frame without a ROI, as in a close
    photo: the 90th percentile of the index lands on leaves, so the soil's spread measured up to
    it put the threshold above them. Measured: 11 of 12 found; with the soil statistics from the
    plain percentiles only (no Otsu split) 8 of 12."""
    found = 0
    for seed in range(12):
        rng = np.random.default_rng(seed)
        soil = (int(rng.integers(70, 120)), int(rng.integers(110, 150)), int(rng.integers(130, 170)))
        g = int(rng.integers(100, 135))
        leaf = (int(rng.integers(55, 80)), g, g - int(rng.integers(10, 30)))
        img = _soil(rng, (720, 1280), colour=soil)
        c = np.array([640 + rng.uniform(-40, 40), 360 + rng.uniform(-20, 20)])
        for k in range(6):
            a = 2 * np.pi * k / 6 + rng.uniform(-0.3, 0.3)
            ln = 300 * rng.uniform(0.7, 1.0)
            m = (c[0] + 0.5 * ln * math.cos(a), c[1] + 0.5 * ln * math.sin(a))
            cv2.ellipse(img, (round(m[0]), round(m[1])), (int(ln / 2), int(ln * 0.22)), math.degrees(a), 0, 360, leaf, -1, cv2.LINE_AA)
        det = detect_centre(cv2.GaussianBlur(img, (0, 0), 1.5))
        found += det.reason is None and math.hypot(det.pixel[0] - c[0], det.pixel[1] - c[1]) < 0.3 * 300
    assert found >= 10, found  # measured 11


def test_clover_with_unseen_stalks_centre_where_trefoils_point_away() -> None:
    """3–6 trefoils on uneven, invisible petioles (1.2–3.5 leaflet lengths) round an empty
    centre, unevenly spaced: the median of the parts' centroids is pulled by the long petioles;
    the middle leaflets point straight away from the centre (`compound_centre`, asked before the
    component median). Measured: 10 of 12 within 0.1 R; with the component median first 6."""
    errs = []
    for k in range(12):
        rng = np.random.default_rng(200 + k)
        img = _soil(rng, (720, 1280), colour=(int(rng.integers(50, 100)), int(rng.integers(80, 130)), int(rng.integers(110, 170))))
        c = np.array([640 + rng.uniform(-80, 80), 360 + rng.uniform(-50, 50)])
        col = (int(rng.integers(30, 70)), int(rng.integers(110, 170)), int(rng.integers(40, 90)))
        n, s = int(rng.integers(3, 7)), rng.uniform(14, 26)
        R = 0.0
        for a in rng.uniform(0, 2 * np.pi) + np.cumsum(rng.dirichlet(np.full(n, 2.0)) * 2 * np.pi):
            P = s * rng.uniform(1.2, 3.5)
            _trefoil(img, c + P * np.array([math.cos(a), math.sin(a)]), a, s, col)
            R = max(R, P + s)
        det = detect_centre(cv2.GaussianBlur(img, (0, 0), 1.0))
        errs.append(math.inf if det.pixel is None else math.hypot(det.pixel[0] - c[0], det.pixel[1] - c[1]) / R)
    assert sum(e < 0.1 for e in errs) >= 9, np.round(errs, 3)


def test_clover_with_visible_stalks_centre_where_they_meet() -> None:
    """3–5 trefoils turned any way (so their leaflets do not point back to the centre) on long
    thin stalks darker than the soil and no greener: the vegetation index does not segment the
    stalks, the line detector of `capm_field.stalks` does. Measured: 5 of 12 within 0.1 R (all
    five by `stalk_centre`, ≤ 0.04 R); without it 1 of 12 (the others 0.3–0.8 R off: compound
    rays from turned trefoils, medians of uneven parts; the rest are stage-1 choices of one
    trefoil, which stalks do not mend)."""
    errs = []
    for k in range(12):
        rng = np.random.default_rng(300 + k)
        img = _soil(rng, (720, 1280), colour=(int(rng.integers(60, 110)), int(rng.integers(90, 130)), int(rng.integers(120, 170))))
        c = np.array([640 + rng.uniform(-80, 80), 360 + rng.uniform(-50, 50)])
        col = (int(rng.integers(30, 70)), int(rng.integers(110, 170)), int(rng.integers(40, 90)))
        stalk = tuple(int(v * 0.55) for v in img[int(c[1]), int(c[0])])  # the soil's colour, darker
        n, s = int(rng.integers(3, 6)), rng.uniform(12, 18)
        R = 0.0
        for a in rng.uniform(0, 2 * np.pi) + np.cumsum(rng.dirichlet(np.full(n, 2.0)) * 2 * np.pi):
            P = s * rng.uniform(2.0, 4.0)
            hub = c + P * np.array([math.cos(a), math.sin(a)])
            cv2.line(img, (round(c[0]), round(c[1])), (round(hub[0]), round(hub[1])), stalk, 1, cv2.LINE_AA)
            _trefoil(img, hub, rng.uniform(0, 2 * np.pi), s, col)
            R = max(R, P + s)
        det = detect_centre(cv2.GaussianBlur(img, (0, 0), 0.7))
        errs.append(math.inf if det.pixel is None else math.hypot(det.pixel[0] - c[0], det.pixel[1] - c[1]) / R)
    assert sum(e < 0.1 for e in errs) >= 4, np.round(errs, 3)


def test_stalk_centre_declines_a_single_blob_and_lines_outside_the_leaves() -> None:
    """`stalk_centre` answers only for plants of ≥ 2 leaf clusters, and not where two lines from
    the leaves meet away from them (straw: beyond MAX_BARE of the plant and outside the hull of
    its leaves), while it finds the same meeting point when a third leaf puts it among them."""
    from capm_field.stalks import stalk_points

    def stalk_centre(*a):
        return stalk_points(*a)[0]

    rng = np.random.default_rng(5)
    grey = (0.5 + 0.02 * rng.standard_normal((200, 200))).astype(np.float32)
    blob = np.zeros((200, 200), np.uint8)
    cv2.circle(blob, (100, 100), 30, 1, -1)
    assert stalk_centre(grey, np.zeros_like(grey), blob > 0, blob > 0) is None
    two = np.zeros((200, 200), np.uint8)
    cv2.circle(two, (80, 100), 14, 1, -1)
    cv2.circle(two, (120, 100), 14, 1, -1)
    g = grey.copy()
    cv2.line(g, (86, 88), (114, 40), 0.3, 1, cv2.LINE_AA)  # two dark lines from the leaves
    cv2.line(g, (114, 88), (114, 40), 0.3, 1, cv2.LINE_AA)  # meet at (114, 40), outside them
    assert stalk_centre(g, np.zeros_like(g), two > 0, two > 0) is None
    three = two.copy()
    cv2.circle(three, (114, 12), 10, 1, -1)  # a leaf beyond the meeting point
    X = stalk_centre(g, np.zeros_like(g), three > 0, three > 0)
    assert X is not None and math.hypot(X[0] - 114, X[1] - 40) < 6, X


def test_faint_stalks_are_measured_against_the_soil_not_against_straws(monkeypatch) -> None:
    """Three leaves on long faint stalks meeting out among them, two straight straws in the soil
    round the plant: the soil's reference line strength is its 99th percentile capped at
    TAIL_K × its 90th (`stalks._soil_ref`), so the straws (and the stalks' own middle parts, which
    lie as far from the leaves as the soil it is measured on) do not lift it over the stalks.
    Uncapped, the stalks are not found (bench seed 4 case 159, a clover, 24.0 → 0.8 mm)."""
    import capm_field.stalks as stalks

    rng = np.random.default_rng(7)
    g = cv2.GaussianBlur((0.5 + 0.02 * rng.standard_normal((240, 240))).astype(np.float32), (0, 0), 0.8)
    leaves = np.zeros((240, 240), np.uint8)
    c = (120, 130)
    for x, y, r in ((70, 80, 16), (175, 85, 14), (115, 45, 13)):
        cv2.circle(leaves, (x, y), r, 1, -1)
        d = (np.array(c, float) - (x, y)) / math.hypot(c[0] - x, c[1] - y)
        cv2.line(g, (round(x + d[0] * (r - 2)), round(y + d[1] * (r - 2))), c, 0.6, 1, cv2.LINE_AA)
    for x0, y0, a in ((20, 210, 0.4), (200, 200, 2.0)):  # straws, far stronger lines than the stalks
        cv2.line(g, (x0, y0), (round(x0 + 30 * math.cos(a)), round(y0 - 30 * math.sin(a))), 0.85, 2, cv2.LINE_AA)
    lv = leaves > 0
    X = stalks.stalk_points(g, np.zeros_like(g), lv, lv)[0]
    assert X is not None and math.hypot(X[0] - c[0], X[1] - c[1]) < 5, X
    monkeypatch.setattr(stalks, "TAIL_K", 0.0)
    assert stalks.stalk_points(g, np.zeros_like(g), lv, lv)[0] is None


def test_the_soil_reference_line_strength_is_capped_but_not_to_nothing() -> None:
    """`stalks._soil_ref`: a textured soil keeps its 99th percentile; straws in 2 % of it are capped
    to TAIL_K × the 90th; a soil flat (zero strength) in 95 % of it is not cut below 1/TAIL_FLOOR
    of its 99th (its few textured pixels would all read as lines)."""
    from capm_field import stalks

    rng = np.random.default_rng(3)
    tex = np.abs(rng.standard_normal(20_000)).astype(np.float32)
    assert stalks._soil_ref(tex) == pytest.approx(np.percentile(tex, 99), rel=0.02)  # (its p99 is ~1.6× its p90)
    straw = tex.copy()
    straw[:400] = 40.0  # 2 % of the soil: a straw's line strength
    assert stalks._soil_ref(straw) == pytest.approx(stalks.TAIL_K * np.percentile(straw, 90), rel=0.02)
    flat = np.zeros(20_000, np.float32)
    flat[:1000] = tex[:1000]  # texture in 5 % of it
    assert stalks._soil_ref(flat) == pytest.approx(np.percentile(flat, 99) / stalks.TAIL_FLOOR, rel=0.02)


def test_lone_stalk_centre_is_its_end_at_the_rest_of_the_plant() -> None:
    """One stalk between a lone leaf and the rest of the plant (three overlapping leaves), no
    second stalk to meet: the centre is the stalk's end on the side of the rest (bench seed 3 case
    27, a clover: 22.3 → 1.6 mm). With the two clusters of equal size there is no answer, nor
    when the leaf it carries outweighs only the cluster it reaches (not the rest), and a second
    stalk to another cluster makes it no lone stalk."""
    from capm_field.stalks import stalk_points

    def scene(rest: tuple, lone_r: int, extra: bool = False):
        rng = np.random.default_rng(5)
        g = (0.5 + 0.02 * rng.standard_normal((320, 320))).astype(np.float32)
        lv = np.zeros((320, 320), np.uint8)
        for c, r in rest:
            cv2.circle(lv, c, r, 1, -1)
        cv2.circle(lv, (100, 100), lone_r, 1, -1)
        cv2.line(g, (100 + lone_r - 3, 100 + lone_r - 3), (172, 172), 0.3, 1, cv2.LINE_AA)
        if extra:  # a second lone leaf on its own stalk
            cv2.circle(lv, (100, 240), 12, 1, -1)
            cv2.line(g, (111, 235), (166, 201), 0.3, 1, cv2.LINE_AA)
        return g, lv > 0

    mass = (((190, 190), 25), ((215, 170), 20), ((210, 220), 18))
    g, lv = scene(mass, 12)
    meet, lone, _ = stalk_points(g, np.zeros_like(g), lv, lv)
    assert meet is None and lone is not None and math.hypot(lone[0] - 172, lone[1] - 172) < 4, lone
    g, lv = scene((((190, 190), 14),), 14)
    assert stalk_points(g, np.zeros_like(g), lv, lv)[1] is None
    g, lv = scene(mass, 12, extra=True)
    assert stalk_points(g, np.zeros_like(g), lv, lv)[1] is None
    # a big old leaf on its stalk, small separate leaves round the stem (photo-like amaranth):
    # its cluster outweighs the one the stalk reaches, not the rest of the plant: no answer
    g, lv = scene((((186, 186), 12), ((210, 160), 12), ((214, 214), 12)), 22)
    assert stalk_points(g, np.zeros_like(g), lv, lv)[1] is None


def trefoil(lv: np.ndarray, hub: tuple, heading: float, r: int = 10, d: int = 11) -> None:
    """Three round leaflets round a hub: the middle one along `heading`, the side ones at ±2 rad
    (as the bench's clovers are drawn), so the petiole enters between the side ones, at the hub."""
    for da in (-2.0, 0.0, 2.0):
        a = heading + da
        cv2.circle(lv, (int(round(hub[0] + d * math.cos(a))), int(round(hub[1] + d * math.sin(a)))), r, 1, -1)


@pytest.mark.parametrize("carried_first", [True, False])
def test_lone_stalk_between_two_trefoils_ends_where_it_only_touches(monkeypatch, carried_first: bool) -> None:
    """One stalk between two trefoils of equal size (no side holds most leaves): it enters the
    trefoil it carries at its hub and only touches the other's rim, where the centre is (bench seed
    31 case 231, a clover: 36.8 → 13.1 mm). The end is told by how deep in its cluster it lies, so
    swapping which trefoil the stalk enters swaps the answer; with `stalks.CARRIED_END` off there is
    none, and the answer is flagged as this rule's (the cascade asks the finer stalk grid first)."""
    from capm_field import stalks

    rng = np.random.default_rng(7)
    g = (0.5 + 0.02 * rng.standard_normal((320, 320))).astype(np.float32)
    lv = np.zeros((320, 320), np.uint8)
    a, b = np.array([100.0, 110.0]), np.array([210.0, 190.0])
    u = (b - a) / np.linalg.norm(b - a)
    if carried_first:  # the stalk carries trefoil a: its middle leaflet points away from b
        trefoil(lv, tuple(a), math.atan2(-u[1], -u[0]))
        trefoil(lv, tuple(b + 12 * u), math.atan2(u[1], u[0]) + 0.9)  # b's leaflet rim faces the stalk
        start, end = a, b - 9 * u
    else:
        trefoil(lv, tuple(b), math.atan2(u[1], u[0]))
        trefoil(lv, tuple(a - 12 * u), math.atan2(-u[1], -u[0]) + 0.9)
        start, end = b, a + 9 * u
    cv2.line(g, tuple(int(round(v)) for v in start), tuple(int(round(v)) for v in end), 0.3, 1, cv2.LINE_AA)
    leaves = lv > 0
    meet, lone, carried = stalks.stalk_points(g, np.zeros_like(g), leaves, leaves)
    assert meet is None and lone is not None and carried, (meet, lone, carried)
    assert np.linalg.norm(lone - end) < 6, (lone, end)
    monkeypatch.setattr(stalks, "CARRIED_END", False)
    assert stalks.stalk_points(g, np.zeros_like(g), leaves, leaves)[1] is None


def test_blue_green_leaves_are_plants() -> None:
    """Glaucous, blue-green leaves (RGB ≈ 56, 112, 94: green far above red, barely above blue)
    on red, sandy, brown and grey soils are found (the green-over-blue test alone said
    "no_plant" for 11 of 17 such plants in bench/other_renderer_plants.py); blue-grey stones
    on the same soils stay "no_plant"."""
    rng = np.random.default_rng(4)
    soils = ((60, 85, 140), (125, 165, 190), (62, 88, 118), (102, 108, 112))  # BGR
    found = 0
    for k in range(8):
        img = _soil(rng, (720, 1280), colour=soils[k % 4])
        c = np.array([rng.uniform(450, 830), rng.uniform(250, 470)])
        col = np.array([94, 112, 56]) * rng.uniform(0.8, 1.2)
        _lens_rosette(img, rng, c, rng.uniform(50, 120), tuple(col.tolist()))
        det = detect_centre(cv2.GaussianBlur(img, (0, 0), 1.0))
        found += det.reason is None and math.hypot(det.pixel[0] - c[0], det.pixel[1] - c[1]) < 30
        stones = _soil(rng, (720, 1280), colour=soils[k % 4])
        for _ in range(6):
            p = (int(rng.uniform(300, 980)), int(rng.uniform(150, 570)))
            cv2.circle(stones, p, int(rng.uniform(8, 25)), (150, 140, 120), -1, cv2.LINE_AA)  # blue-grey
        assert detect_centre(cv2.GaussianBlur(stones, (0, 0), 1.0)).reason == "no_plant"
    assert found >= 7, found


def test_teal_leaves_that_only_the_second_look_segments_are_plants() -> None:
    """Teal leaves (G only 12–13 above B, far above R) on red and brown soils: the soil white
    balance lifts blue, so G − max(R, B) leaves them at the soil's level and the first look
    says "no_plant"; the CIELAB look segments them, and their colour (far greener than red,
    the blue-green rule) makes them a plant rather than a soil tint (it was "no_plant" when
    the second look took vivid colours only)."""
    import capm_field.detector as det_mod

    rng = np.random.default_rng(5)
    for soil in ((60, 85, 140), (62, 88, 118)):  # BGR: red, brown
        for col in ((100, 112, 40), (105, 118, 60)):
            img = _soil(rng, (720, 1280), colour=soil)
            c = np.array([640.0, 360.0])
            _lens_rosette(img, rng, c, 90.0, col)
            img = cv2.GaussianBlur(img, (0, 0), 1.0)
            assert det_mod._detect(img, None).reason == "no_plant"
            det = detect_centre(img)
            assert det.reason is None and math.hypot(det.pixel[0] - c[0], det.pixel[1] - c[1]) < 30, (soil, col, det)


def test_yellow_green_plant_with_one_greener_leaf_is_found_whole() -> None:
    """A large yellow-green rosette (G ≈ R) with one leaf a little greener (G 18 above R): the
    first look segments that leaf alone (G* p90 ≈ 0.005) and answers half a leaf from the centre;
    the CIELAB look, run because the first choice is so faintly green, takes the whole plant
    (it was the leaf before: the first choice was large enough to be taken as it was)."""
    import capm_field.detector as det_mod

    rng = np.random.default_rng(7)
    first_errs, errs = [], []
    for _ in range(6):
        img = _soil(rng, (720, 1280), colour=(95, 110, 115))
        c = np.array([640.0, 360.0])
        _lens_rosette(img, rng, c, 200.0, (35, 118, 116))
        _lens_leaf(img, c, rng.uniform(0, 2 * np.pi), 190.0, 0.18, (40, 128, 110))
        img = cv2.GaussianBlur(img, (0, 0), 1.0)
        first = det_mod._detect(img, None)
        first_errs.append(math.hypot(first.pixel[0] - c[0], first.pixel[1] - c[1]))
        det = detect_centre(img)
        assert det.reason is None, det
        errs.append(math.hypot(det.pixel[0] - c[0], det.pixel[1] - c[1]))
    assert min(first_errs) > 70, np.round(first_errs)  # the first look: on the greener leaf
    assert np.median(errs) < 20 and max(errs) < 70, np.round(errs)


def test_large_pale_yellow_green_rosettes_are_found() -> None:
    """Large rosettes (L 130–180 px in 1280×720) of pale yellow-green leaves (G ≈ R, saturation
    ≈ 0.35) on grey-olive soil: G* leaves them at the soil's level and they are not vivid enough
    for the second look's colour gates, but a candidate that large (≥ 1 % of the window) needs
    less (measured: 6 of 8 found within 0.3 L; 2 of 8 before)."""
    rng = np.random.default_rng(21)
    found = 0
    for _ in range(8):
        img = _soil(rng, (720, 1280), colour=(95, 110, 115))
        c = np.array([rng.uniform(500, 780), rng.uniform(280, 440)])
        L = rng.uniform(130, 180)
        col = (int(rng.integers(72, 80)), int(rng.integers(122, 128)), int(rng.integers(118, 122)))
        _lens_rosette(img, rng, c, L, col)
        det = detect_centre(cv2.GaussianBlur(img, (0, 0), 1.0))
        found += det.reason is None and math.hypot(det.pixel[0] - c[0], det.pixel[1] - c[1]) < 0.3 * L
    assert found >= 5, found


def test_tree_median_of_two_leaves_seen_from_inside_one_is_at_the_stem() -> None:
    """Two broad leaves (cotyledons) joined by a thin stem: seen from the deepest point, inside
    the larger leaf, only the other leaf's end may stand out as a tip, and Σ distance to one tip
    is least at that tip. The far end of the plant is then the second tip and the centre the
    narrow stem between them (measured: 11 of 12 masks within 6 px of the stem's middle; 8 of 12
    before, the other 3 at a leaf end ~50 px away)."""
    from capm_field import tree_median

    rng = np.random.default_rng(5)
    near = 0
    for _ in range(12):
        m = np.zeros((110, 90), np.uint8)
        top = np.array([26 + rng.uniform(-3, 3), 26 + rng.uniform(-3, 3)])
        bot = np.array([60 + rng.uniform(-3, 3), 80 + rng.uniform(-3, 3)])
        cv2.ellipse(m, (int(top[0]), int(top[1])), (int(rng.uniform(15, 18)), int(rng.uniform(12, 15))), rng.uniform(30, 60), 0, 360, 1, -1)
        cv2.ellipse(m, (int(bot[0]), int(bot[1])), (int(rng.uniform(12, 15)), int(rng.uniform(10, 13))), rng.uniform(30, 60), 0, 360, 1, -1)
        cv2.line(m, (int(top[0]), int(top[1])), (int(bot[0]), int(bot[1])), 1, int(rng.integers(3, 6)))
        uv, _, _ = tree_median.tree_median(m.astype(bool))
        near += math.hypot(uv[0] - 45.0, uv[1] - 52.0) < 6.0
    assert near >= 11, near


def _hollow_rosette(rng) -> tuple[np.ndarray, np.ndarray]:
    """A rosette mask whose leaf bases ring a bare middle (soil or pale stalks between them)."""
    m = np.zeros((120, 120), np.uint8)
    c = np.array([60 + rng.uniform(-3, 3), 60 + rng.uniform(-3, 3)])
    n, a0 = int(rng.integers(5, 9)), rng.uniform(0, 2 * np.pi)
    for k in range(n):
        a, L, W = a0 + 2 * np.pi * k / n + rng.uniform(-0.25, 0.25), rng.uniform(28, 48), rng.uniform(7, 11)
        mid = c + (12 + L / 2) * np.array([math.cos(a), math.sin(a)])
        cv2.ellipse(m, (int(mid[0]), int(mid[1])), (int(L / 2), int(W)), math.degrees(a), 0, 360, 1, -1)
    cv2.circle(m, (int(c[0]), int(c[1])), 14, 1, 4)
    return m.astype(bool), c


def _leaf_clusters_on_hidden_stalks(rng) -> tuple[np.ndarray, np.ndarray]:
    """Purslane-like mask: 3–5 arms of two leaf clusters each round a small hub, the stalks
    between them not in the mask and the gaps wider than `tree_median`'s crossing band."""
    m = np.zeros((240, 240), np.uint8)
    c = np.array([120 + rng.uniform(-4, 4), 120 + rng.uniform(-4, 4)])
    n, a0, R = int(rng.integers(3, 6)), rng.uniform(0, 2 * np.pi), rng.uniform(80, 100)
    cv2.circle(m, (int(c[0]), int(c[1])), 3, 1, -1)
    for k in range(n):
        a, L = a0 + 2 * np.pi * k / n + rng.uniform(-0.3, 0.3), R * rng.uniform(0.8, 1.0)
        for t in (0.45 * L, L):
            p = c + t * np.array([math.cos(a), math.sin(a)])
            cv2.circle(m, (int(p[0]), int(p[1])), int(0.07 * R), 1, -1)
    return m.astype(bool), c


@pytest.mark.parametrize("make, flag, tol, n_on, n_off", [
    (_hollow_rosette, "FILL_HOLES", 0.06, 10, 2),
    (_leaf_clusters_on_hidden_stalks, "BRIDGE_ALL", 0.05, 11, 3),
])
def test_tree_median_crosses_a_bare_middle_and_gaps_between_leaf_clusters(monkeypatch, make, flag, tol, n_on, n_off) -> None:
    """`crossing_cost`: soil the plant encloses costs as much as the plant (paths round a bare
    middle pulled the median onto a leaf: 0.09–0.12 × size off, 0.01–0.08 with it), and leaf
    clusters further apart than the band are joined across the hull (else only the part holding
    the provisional centre has tips: 0.36–0.41 × size off on most masks). Measured on 12 masks with
    every tip counting 1 (`TIP_SPREAD` 0: its bunch weights move these masks' answers both ways, 10 → 9
    rosettes within 0.06 × size, and 3 → 4 clusters without the bridge)."""
    from capm_field import geodesic, tree_median

    monkeypatch.setattr(tree_median, "TIP_SPREAD", 0.0)

    def near(on: bool) -> int:
        monkeypatch.setattr(geodesic, flag, on)
        rng, k = np.random.default_rng(3), 0
        for _ in range(12):
            m, c = make(rng)
            ys, xs = np.nonzero(m)
            uv, _, _ = tree_median.tree_median(m)
            k += math.hypot(uv[0] - c[0], uv[1] - c[1]) < tol * math.hypot(np.ptp(xs) + 1, np.ptp(ys) + 1)
        return k

    assert near(True) >= n_on
    assert near(False) <= n_off


@pytest.mark.parametrize("make", [_hollow_rosette, _leaf_clusters_on_hidden_stalks])
def test_tree_median_graph_stays_within_the_plants_hull(monkeypatch, make) -> None:
    """`crossing_cost` with `HULL_BAND`: no finite-cost pixel lies outside the plant's convex hull, the
    graph has ≥ 10 % fewer nodes than with the band all round, and the tree median moves by
    < 0.02 × size (measured on these 12 + 12 masks: 14–27 % fewer nodes, the median unmoved)."""
    from capm_field import geodesic, tree_median

    rng = np.random.default_rng(5)
    for _ in range(12):
        m, _ = make(rng)
        ys, xs = np.nonzero(m)
        size = math.hypot(np.ptp(xs) + 1, np.ptp(ys) + 1)
        hull = np.zeros(m.shape, np.uint8)
        cv2.fillConvexPoly(hull, cv2.convexHull(np.c_[xs, ys].astype(np.int32)), 1)
        monkeypatch.setattr(geodesic, "HULL_BAND", True)
        cut = np.isfinite(geodesic.crossing_cost(m, size))
        uv_cut = tree_median.tree_median(m)[0]
        monkeypatch.setattr(geodesic, "HULL_BAND", False)
        ring = np.isfinite(geodesic.crossing_cost(m, size))
        uv_ring = tree_median.tree_median(m)[0]
        assert not (cut & (hull == 0)).any()
        assert (ring & (hull == 0)).any() and cut.sum() <= 0.9 * ring.sum(), (cut.sum(), ring.sum())
        assert math.hypot(*(uv_cut - uv_ring)) < 0.02 * size, (uv_cut, uv_ring)


def test_five_kinds_from_another_renderer_with_a_roi() -> None:
    """25 weeds (grass, clover, seedling, rosette, lobed) from bench/other_renderer_plants.py,
    a renderer written without sim_bench or the detector, with a ROI around each (seed 7; these
    cases were not used for tuning: close-up crops of its cases 39 and 47 led to FAINT_SIGMA and
    the cyan rule). Measured (session 19): 23 found, 20 within 0.2 of the plant size."""
    orp = bench_module("other_renderer_plants")
    found = within = 0
    for i in range(25):
        img, truth, S, _ = orp.render(np.random.default_rng([7, i]), orp.KINDS[i % 5])
        r = np.random.default_rng([7, i, 1])
        rad, a = r.uniform(1.2, 2.5) * S / 2, r.uniform(0, 2 * np.pi)
        o = r.uniform(0, 0.3 * rad)
        det = detect_centre(img, ((truth[0] + o * math.cos(a), truth[1] + o * math.sin(a)), (2 * rad, 2 * rad), 0.0))
        ok = det.reason is None and det.pixel is not None
        found += ok
        within += ok and math.hypot(det.pixel[0] - truth[0], det.pixel[1] - truth[1]) < 0.2 * S
    assert found >= 21 and within >= 15, (found, within)


def test_bluish_green_plants_green_in_the_raw_image_are_found() -> None:
    """Two bluish-green weeds of bench/other_renderer_plants.py (seed 0 case 60, a grass tuft on
    dark wet soil; seed 2 case 92, a seedling on brown soil), whole frames without a ROI: too
    dull for the vivid and teal rules of the second look ("no_plant" before `_raw_blue_green`),
    but green above red and blue in the camera's own colours and saturated there. Centre within
    0.15 S (measured 0.004 and 0.11 S: since the glaucous rule takes G* p90 ≥ 0.04, a pale part of
    the seedling joins it and the leaf-axis estimator answers; 0.03 S before)."""
    orp = bench_module("other_renderer_plants")
    for seed, i in ((0, 60), (2, 92)):
        img, truth, S, _ = orp.render(np.random.default_rng([seed, i]), orp.KINDS[i % 5])
        det = detect_centre(img)
        assert det.reason is None and math.hypot(det.pixel[0] - truth[0], det.pixel[1] - truth[1]) < 0.15 * S, (seed, i, det)


@pytest.mark.parametrize("ratio", [1.1, 1.45, 1.5, 1.7, 2.0, 2.5, 3.3, 4.7])
def test_fast_downscale_matches_area_resampling(ratio: float) -> None:
    """The stage-1 downscale (bilinear + integer box average) stays within a grey level of
    INTER_AREA on a textured image, and a one-pixel stem at any phase keeps ≥ 0.7 of the
    weight INTER_AREA gives it (bilinear resampling alone drops it at ratios near 2)."""
    from capm_field.vegetation import resize_down

    rng = np.random.default_rng(int(ratio * 100))
    tex = cv2.GaussianBlur(rng.integers(0, 256, (300, 420, 3), dtype=np.uint8), (0, 0), 1.5)
    size = (round(420 / ratio), round(300 / ratio))
    fast = resize_down(tex, size).astype(float)
    ref = cv2.resize(tex, size, interpolation=cv2.INTER_AREA).astype(float)
    assert fast.shape == ref.shape
    assert np.abs(fast - ref).mean() < 1.0
    for x in range(0, 60):
        line = np.zeros((40, 420, 3), np.uint8)
        line[:, 100 + x] = 255
        sz = (size[0], round(40 / ratio))
        kept = int(resize_down(line, sz)[..., 1].max())
        area = int(cv2.resize(line, sz, interpolation=cv2.INTER_AREA)[..., 1].max())
        assert kept >= 0.7 * area, (x, kept, area)


def test_glaucous_rule_takes_coloured_leaves_not_neutral_stones() -> None:
    """Middling-contrast blue-green leaves (features measured on another renderer's glaucous
    plant, rejected by every other colour rule) are plant-like; the same features with the raw
    saturation of a neutral stone (which the white balance on a purplish soil turns as green)
    are not."""
    from capm_field.candidates import plant_like

    leaf = dict(area=161.0, gsig=14.2, g_p90=0.078, gb=0.064, gr=0.040, sat=0.22, g_raw=0.0, sat_raw=0.30,
                gm_raw=0.044, elong=1.2, area_frac=0.003, d=0.68)
    assert plant_like(leaf)
    assert not plant_like(dict(leaf, sat_raw=0.03))
    assert not plant_like(dict(leaf, gsig=6.0))  # too close to the soil's noise
    assert plant_like(dict(leaf, g_p90=0.042))  # a pale seedling (bench seed 2 case 5)
    assert not plant_like(dict(leaf, g_p90=0.035))
    assert not plant_like(leaf, vivid=True)  # the second look keeps its own, vivid-only rules


def test_large_raw_green_rule_takes_leaves_on_two_tone_soil_not_stones_under_a_green_cast() -> None:
    """A large candidate green above red and blue before and after the white balance is a plant
    at any soil σ: bench seed 2 case 54 (grass on a soil half brown, half grey: 4 σ out, gb just
    under the base rule's 0.07) and seed 3 case 38 (grass, second look) are found near their
    centre. A grey stone under a green cast (bench/stones_on_soils.py, sat_raw ≤ 0.21) and a
    speck of the grass's colour are not taken by this rule."""
    from capm_field.candidates import plant_like

    grass = dict(area=773.0, area_frac=0.0099, gb=0.069, gr=0.072, sat=0.224, sat_raw=0.284, g_raw=0.073,
                 gm_raw=0.087, gsig=3.99, g_p90=0.0895, elong=1.13, d=0.3)
    assert plant_like(grass) and plant_like(grass, vivid=True)
    stone = dict(grass, area_frac=0.0062, gb=0.058, gr=0.040, sat=0.167, sat_raw=0.202, g_raw=0.048, gm_raw=0.060, gsig=8.3)
    assert not plant_like(stone) and not plant_like(stone, vivid=True)
    assert not plant_like(dict(grass, sat_raw=0.21))
    assert not plant_like(dict(grass, area_frac=0.001))  # a speck needs the other rules
    for seed, i in ((2, 54), (3, 38)):
        case = make_case(seed, i, CAM, TaskConfig().delta, bare=False)
        det = detect_centre(case.scene.render(case.T, CAM), roi_from_troi(CAM, case.T, case.troi_centre, case.troi_radius))
        assert det.reason is None, (seed, i, det)
        assert np.linalg.norm(ground_centre(CAM, case.T, det) - case.scene.weeds[0].centre) < 0.015, (seed, i, det)


def test_pale_seedling_found_by_local_contrast_while_yellow_soil_tints_are_not() -> None:
    """Second look, colour band where pale seedlings and soil tints overlap (gb 0.085–0.15, sat
    0.29–0.42): bench seed 3 case 233, a yellow-green seedling missed by both colour rules, is a
    plant by its contrast with the soil right round it, and so is seed 2 case 25, two cotyledons
    in a line (elongation 3.7: missed while the rule stopped at 3.5); bench seed 3 case 8, a
    yellow soil whose tints fall in the same band (7 components), stays bare."""
    for seed, i, plant in ((3, 233, True), (2, 25, True), (3, 8, False)):
        bare = set(np.random.default_rng(seed).choice(300, 45, replace=False).tolist())
        assert (i in bare) != plant
        case = make_case(seed, i, CAM, TaskConfig().delta, bare=i in bare)
        img = case.scene.render(case.T, CAM)
        det = detect_centre(img, roi_from_troi(CAM, case.T, case.troi_centre, case.troi_radius))
        if plant:
            assert det.reason is None, det
            assert np.linalg.norm(ground_centre(CAM, case.T, det) - case.scene.weeds[0].centre) < 0.008
        else:
            assert det.reason == "no_plant", det


@settings(max_examples=300, deadline=None)
@given(v=hnp.arrays(np.float32, st.integers(1, 400), elements=st.floats(-1.0, 1.0, width=32)),
       q=st.sampled_from([0.5, 10.0, 50.0, 90.0, 99.5, 100.0]))
def test_fast_order_statistics_equal_numpy(v, q) -> None:
    """The detector's one-partition percentiles and medians give numpy's values bit for bit (the
    bench answers must not move when they replace np.percentile / np.median)."""
    from capm_field.order_stats import median, percentile, row_medians

    assert percentile(v, q) == float(np.percentile(v, q))
    assert percentile(v, (q, 50.0)) == tuple(float(x) for x in np.percentile(v, [q, 50.0]))
    assert median(v) == float(np.median(v))
    rows = np.stack([v, v[::-1] * 2])
    assert np.array_equal(row_medians(rows), np.median(rows, axis=1))
    assert math.isnan(median(v[:0]))  # as np.median (which also warns)


def test_closed_form_elongation_matches_the_covariance_eigenvalues() -> None:
    """`_elongation` (2 × 2 eigenvalues in closed form) equals √(λ1/λ2) of np.cov + ¼ px² to 1e-9."""
    from capm_field.order_stats import elongation

    rng = np.random.default_rng(0)
    for n in (2, 3, 10, 200, 5000):
        xs = rng.integers(0, 300, n)
        ys = (0.3 * xs + rng.integers(0, 40, n)).astype(np.int64)
        ev = np.linalg.eigvalsh(np.cov(np.c_[xs, ys].T.astype(float)) + 0.25 * np.eye(2))
        assert math.isclose(elongation(xs, ys), math.sqrt(ev[1] / ev[0]), rel_tol=1e-9)
    assert math.isclose(elongation(np.arange(50), np.zeros(50, np.int64)), math.sqrt((np.var(np.arange(50), ddof=1) + 0.25) / 0.25))


def _threshold_reference(v: np.ndarray) -> tuple[float, float, float]:
    """`vegetation_mask.threshold` in plain numpy, without its shortcuts (the oracle of the test below)."""
    from capm_field.vegetation_mask import BIG_PLANT, BIG_SEP, THR_FLOOR, THR_SIGMAS

    lo, med, p90, hi = (float(x) for x in np.percentile(v, [0.5, 50, 90, 99.5]))
    sig = max((p90 - med) / 1.28, 0.004)
    if p90 > med and hi > lo:
        q = np.clip((v - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)
        t = lo + cv2.threshold(q.reshape(1, -1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)[0] * (hi - lo) / 255.0
        low, up = v[v <= t], v[v > t]
        if 1.0 - len(low) / len(v) >= BIG_PLANT and len(low) > 100:
            m_l, p_l = (float(x) for x in np.percentile(low, [50, 90]))
            s_l = max((p_l - m_l) / 1.28, 0.004)
            m_u = float(np.median(up))
            if m_u > 0 and m_u - m_l >= BIG_SEP * s_l:
                med, sig = m_l, s_l
    thr = float(np.clip(med + THR_SIGMAS * sig, THR_FLOOR, 0.10))
    above = v[v > thr]
    return thr, med, float(np.median(above) - med) if len(above) else 0.0


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(150, 3000), share=st.floats(0.0, 0.6),
       soil=st.floats(-0.08, 0.02), green=st.floats(-0.05, 0.3))
def test_threshold_equals_its_plain_numpy_definition(seed, n, share, soil, green) -> None:
    """`threshold` (one-partition percentiles; the Otsu classes' percentiles skipped when under
    half of the upper class is > 0) gives the plain numpy definition's values bit for bit, on soils
    with a green class of any share and level (also one below zero, where the skip applies)."""
    from capm_field.vegetation_mask import threshold

    rng = np.random.default_rng(seed)
    k = int(share * n)
    v = np.r_[rng.normal(soil, 0.01, n - k), rng.normal(green, 0.02, k)].astype(np.float32)
    assert threshold(v) == _threshold_reference(v)


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 70), w=st.integers(1, 70), share=st.floats(0.0, 1.0),
       holes=st.floats(0.0, 0.3))
def test_grid_graph_equals_the_coo_built_matrix(seed, h, w, share, holes) -> None:
    """`geodesic.GridGraph.csr` (CSR built directly) is the matrix scipy builds from the edge list
    (COO → CSR): the same rows, columns and weights, so Dijkstra's distances cannot move."""
    import scipy.sparse as sp

    from capm_field.geodesic import GAP_COST, grid_graph

    rng = np.random.default_rng(seed)
    cost = np.where(rng.random((h, w)) < share, 1.0, GAP_COST)
    cost[rng.random((h, w)) < holes] = np.inf
    graph, node = grid_graph(cost)
    G = graph.csr()
    ok = np.isfinite(cost)
    assert np.array_equal(node[ok], np.arange(int(ok.sum()))) and (node[~ok] == -1).all()
    rows, cols, wts = [], [], []
    for y, x in zip(*np.nonzero(ok)):
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                yy, xx = y + dy, x + dx
                if (dy or dx) and 0 <= yy < h and 0 <= xx < w and ok[yy, xx]:
                    rows.append(node[y, x])
                    cols.append(node[yy, xx])
                    wts.append((math.sqrt(2) if dy and dx else 1.0) * 0.5 * (cost[y, x] + cost[yy, xx]))
    want = sp.csr_matrix((wts, (rows, cols)), shape=G.shape)
    want.sort_indices()
    assert np.array_equal(G.indptr, want.indptr) and np.array_equal(G.indices, want.indices)
    assert np.array_equal(G.data, want.data)


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 120), w=st.integers(1, 120),
       sigma=st.floats(0.3, 4.0), level=st.floats(0.3, 0.7))
def test_components_equal_opencv_default_labelling(seed, h, w, sigma, level) -> None:
    """`components` (Grana's labelling) gives the labels, statistics and centroids of
    cv2.connectedComponentsWithStats(…, connectivity=8) on blobby masks of any shape."""
    from capm_field.components import components

    noise = np.random.default_rng(seed).random((h, w)).astype(np.float32)
    mask = cv2.GaussianBlur(noise, (0, 0), sigma) > level
    n0, lab0, st0, c0 = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    n1, lab1, st1, c1 = components(mask)
    assert n1 == n0
    assert np.array_equal(lab1, lab0) and np.array_equal(st1, st0)
    assert np.allclose(c1, c0, equal_nan=True)


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 30), w=st.integers(1, 30), share=st.floats(0.05, 1.0))
def test_candidate_colour_features_are_numpys_medians_of_their_definitions(seed, h, w, share) -> None:
    """`candidate_features` computes its colour medians on per-channel planes (speed); each equals
    np.median of its defining expression over the (n, 3) pixels, bit for bit."""
    from capm_field.candidates import candidate_features

    rng = np.random.default_rng(seed)
    gm = rng.random((h, w)) < share
    if not gm.any():
        return
    small = rng.integers(0, 256, (h, w, 3)).astype(np.uint8)
    vi = rng.normal(0.0, 0.05, (h, w)).astype(np.float32)
    gains = rng.uniform(0.8, 1.25, 3).astype(np.float32)
    f = candidate_features(gm, vi, small, gains, 0.01, 0.02, np.array([5.0, 5.0]), 10.0)
    raw = small[gm].astype(np.float32)
    pc = raw * gains
    ps, rs = pc.sum(1) + 30, raw.sum(1) + 30
    want = {
        "gb": (pc[:, 1] - pc[:, 0]) / ps,
        "gr": (pc[:, 1] - pc[:, 2]) / ps,
        "sat": (pc.max(1) - pc.min(1)) / (pc.max(1) + 1),
        "g_raw": (raw[:, 1] - raw[:, [0, 2]].max(1)) / rs,
        "sat_raw": (raw.max(1) - raw.min(1)) / (raw.max(1) + 1),
        "gm_raw": (raw[:, 1] - 0.5 * (raw[:, 0] + raw[:, 2])) / rs,
    }
    for k, v in want.items():
        assert f[k] == float(np.median(v)), k


def test_stage_two_without_one_soil_pixel_has_no_centre() -> None:
    """A stage-2 crop that the threshold leaves all "plant" (a part look's low threshold on the
    other part's brighter soil) has no soil to measure widths from: no centre, not a point at
    the crop's corner from a distance transform without zeros (which overflowed)."""
    import warnings

    from capm_field.centre_cascade import centre_fullres

    img = np.zeros((120, 160, 3), np.uint8)
    img[:] = (60, 140, 70)  # green everywhere, including round the plant's box
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        uv, tips, sharp = centre_fullres(img, (60.0, 40.0, 82.0, 58.0), 0.02, -0.05, np.ones(3, np.float32), None)
    assert uv is None and tips == 0


@pytest.mark.parametrize("i", [2, 10, 22, 38])
def test_a_field_photo_is_read_the_same_at_any_size(i: int) -> None:
    """One photo of bench/field_photo_weeds.py (seed 0: grass, a dandelion, grass, a fat-hen; an
    independent renderer, no ROI) shrunk to 160 and 320 px, as rendered (1024–2000 px) and enlarged to
    2400 px on its longer side: the crown is found within 0.15 S each time (measured ≤ 0.06 S;
    every size from 64 to 4000 px found 39–40 of seed 0's first 40 photos, median 0.04–0.10 S)."""
    fpw = field_photos()
    img, truth, S, _ = fpw.render(np.random.default_rng([0, i]), fpw.KINDS[i % len(fpw.KINDS)])
    H, W = img.shape[:2]
    for side in (160, 320, None, 2400):
        k = 1.0 if side is None else side / max(H, W)
        im = img if side is None else cv2.resize(img, (round(W * k), round(H * k)),
                                                 interpolation=cv2.INTER_AREA if k < 1 else cv2.INTER_CUBIC)
        det = detect_centre(im)
        assert det.reason is None, (side, det)
        u, v = ((det.pixel[0] + 0.5) / k - 0.5, (det.pixel[1] + 0.5) / k - 0.5)  # back to the rendered photo
        assert math.hypot(u - truth[0], v - truth[1]) < 0.15 * S, (side, det)


@pytest.mark.parametrize("i", [0, 2, 3, 4, 6])
def test_a_plant_filling_the_frame_is_read(i: int) -> None:
    """Photos of bench/field_photo_weeds.py seed 0 (a dandelion, grass, a clover, a seedling, a thistle; an
    independent renderer, no ROI) cropped to a square of 1.1 S (the plant fills the frame; 93–496 px)
    whose centre is 0.2–0.3 S from the crown: there is little soil to measure, but the crown is found
    within 0.12 S (measured ≤ 0.07 S; the frame's centre is ≥ 0.2 S off). Seeds 0–1, 160 photos each
    (`--fill 1.1`, crop centres within 0.1 S): 97.5 / 99.4 % found, within 0.2 S 89.4 / 87.5 %, none
    > 0.5 S off."""
    fpw = field_photos()
    img, truth, S, _ = fpw.render(np.random.default_rng([0, i]), fpw.KINDS[i % len(fpw.KINDS)])
    rng = np.random.default_rng([0, i, 3])
    for _ in range(50):  # a crop whose centre is 0.2–0.3 S from the crown
        crop, t = fpw.fill_crop(img, truth, S, 1.1, rng, off=0.3)
        if 0.2 * S <= math.hypot(t[0] - (crop.shape[1] - 1) / 2, t[1] - (crop.shape[0] - 1) / 2) <= 0.3 * S:
            break
    else:
        pytest.fail("no crop with its centre 0.2–0.3 S from the crown")
    assert max(crop.shape[:2]) <= 1.1 * S + 1 < min(img.shape[:2])  # a crop, not the photo
    det = detect_centre(crop)
    assert crown_off(det, t, S) < 0.12, det


def _found_only_by_the_rule(kind: str, seed: int, i: int, with_roi: bool, rule_constant: str, monkeypatch) -> None:
    """A field-photo plant (bench/field_photo_weeds.py) is found within 0.25 S; with the colour rule's
    `rule_constant` (in `capm_field.candidates`) set to ∞, "no_plant" with its ROI and an answer > 0.5 S
    off without one. (0.25 S: since session 34 the fat-hen of seed 4 case 28 is located 0.22 S off,
    0.01 S before: −a* from CIE's formulas moved its stage-2 mask, and the tree median, not the
    geometric median, answers. The rule still decides whether it is found at all.)"""
    from capm_field import candidates

    fpw = field_photos()
    img, truth, S, _ = fpw.render(np.random.default_rng([seed, i]), kind)
    roi = fpw.roi_near(seed, i, truth, S) if with_roi else None
    det = detect_centre(img, roi)
    assert crown_off(det, truth, S) < 0.25, det
    monkeypatch.setattr(candidates, rule_constant, math.inf)
    det = detect_centre(img, roi)
    if with_roi:
        assert det.reason == "no_plant", det
    else:
        assert det.reason is None and crown_off(det, truth, S) > 0.5, det


@pytest.mark.parametrize("seed, i, with_roi", [(0, 108, True), (4, 28, True), (0, 108, False), (5, 8, False)])
def test_a_mealy_plant_is_a_plant(seed: int, i: int, with_roi: bool, monkeypatch) -> None:
    """Fat-hens of bench/field_photo_weeds.py (an independent renderer): the mealy bloom leaves them
    whitish (gb 0.04–0.07, saturation 0.14–0.21 after the white balance, below every other colour
    rule), but green above red and blue in the raw image. With its ROI they fill ~20 % of the window,
    without one 3–7 % of the photo. Found within 0.25 S (measured 0.01–0.22 S); without the rule
    (`_mealy`), "no_plant" with the ROI and a small vivid plant elsewhere (0.85–0.90 S off) without."""
    _found_only_by_the_rule("fathen", seed, i, with_roi, "MEALY_FRAC", monkeypatch)


@pytest.mark.parametrize("seed, i, with_roi", [(4, 126, True), (5, 26, True), (0, 156, True), (0, 156, False)])
def test_a_large_teal_plant_is_a_plant(seed: int, i: int, with_roi: bool, monkeypatch) -> None:
    """Thistles of bench/field_photo_weeds.py (an independent renderer) whose leaves are blue-green:
    G* leaves them at the soil's level, −a* segments them whole, but blue at green's level puts their
    gb at −0.01–0.03 and their green above red at gr 0.09–0.14, short of the teal and cyan rules
    (which small candidates need). With the ROI they fill ~15–20 % of the window. Found within 0.2 S
    (measured 0.01–0.07 S); without the rule (`_large_teal`), "no_plant" with the ROI, and without
    one a small plant elsewhere (0.85 S off)."""
    _found_only_by_the_rule("thistle", seed, i, with_roi, "LTEAL_GR", monkeypatch)


def test_a_fan_of_stalks_meeting_outside_the_leaves_hull_is_the_centre(monkeypatch) -> None:
    """bench/field_photo_weeds.py seed 0 case 43 with its ROI: a clover whose reddish petioles fan out
    from the crown to trefoils on one side; the palest trefoil stays under the threshold, so the crown
    lies outside the hull of the leaves found. Stalks of three orientations ≥ 20° apart (the rule's
    least) meet there: found within 0.1 S (measured 0.01 S); 0.46 S off (a trefoil) when a meeting
    outside the hull needs more orientations than there are (`stalks.FAN_STALKS`)."""
    from capm_field import stalks

    fpw = field_photos()
    img, truth, S, _ = fpw.render(np.random.default_rng([0, 43]), "clover")
    roi = fpw.roi_near(0, 43, truth, S)
    det = detect_centre(img, roi)
    assert crown_off(det, truth, S) < 0.1, det
    monkeypatch.setattr(stalks, "FAN_STALKS", 99)
    import capm_field.centre_cascade as cascade
    monkeypatch.setattr(cascade, "HUB_PETIOLES", False)  # (which also finds this crown)
    det = detect_centre(img, roi)
    assert det.reason is None and crown_off(det, truth, S) > 0.3, det


@pytest.mark.parametrize("seed, i", [(1, 43), (4, 63)])
def test_pale_petioles_of_a_large_clover_are_found_on_a_finer_grid(seed: int, i: int, monkeypatch) -> None:
    """Two clovers of bench/field_photo_weeds.py (S ≈ 490–620 px) with its ROI: pale petioles 3–5 px wide
    converge on the crown, but on the stalk grid of ≤ 100 px per plant window (pitch ≥ 5 px) they fade
    into the soil's texture; the second search at ≤ 200 px (`FINE_STALK_PX`, only for compound-leaved
    plants in a window ≥ 200 px) finds where they meet: within 0.1 S (measured 0.02 and 0.04 S), and
    > 0.3 S off (a trefoil's hub) without it."""
    from capm_field import centre_cascade

    fpw = field_photos()
    img, truth, S, _ = fpw.render(np.random.default_rng([seed, i]), "clover")
    roi = fpw.roi_near(seed, i, truth, S)
    det = detect_centre(img, roi)
    assert crown_off(det, truth, S) < 0.1, det
    monkeypatch.setattr(centre_cascade, "FINE_STALK_PX", 0)
    det = detect_centre(img, roi)
    assert det.reason is None and crown_off(det, truth, S) > 0.3, det


def test_stalk_orientations_count_a_piece_between_two_leaves_once() -> None:
    """`stalks._directions`: pieces through X at 0°, 60° and 120° are three orientations; a piece
    between two leaves comes in both ways (0° and 180°) and is one; a piece pointing away from X, or
    whose line misses it, is none."""
    from capm_field.stalks import _directions

    def piece(angle_deg: float, back: float = 6.0) -> tuple:  # middle `back` px before X along its direction
        d = np.array([math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))])
        return (-back * d, d, 4.0, 8.0)

    X = np.zeros(2)
    assert _directions([piece(0), piece(60), piece(120)], X, 1.5, 10.0) == 3
    both_ways = [(np.zeros(2), np.array([1.0, 0.0]), 4.0, 8.0), (np.zeros(2), np.array([-1.0, 0.0]), 4.0, 8.0)]
    assert _directions(both_ways + [piece(60)], X, 1.5, 10.0) == 2
    assert _directions([piece(0, back=-6.0)], X, 1.5, 10.0) == 0  # it points away from X
    assert _directions([(np.array([0.0, 5.0]), np.array([1.0, 0.0]), 4.0, 8.0)], X, 1.5, 10.0) == 0  # misses X


def _stems_with_a_bunch(rng) -> tuple[np.ndarray, np.ndarray]:
    """Three stems ~60 px long from a crown, 120° apart: one ends in a bunch of six small leaves on
    short side stems, the others in one leaf each. Returns (mask, crown (x, y))."""
    m = np.zeros((200, 200), np.uint8)
    c = np.array([100.0, 100.0]) + rng.uniform(-3, 3, 2)
    a0 = rng.uniform(0, 2 * math.pi)

    def pt(p: np.ndarray) -> tuple[int, int]:
        return int(p[0]), int(p[1])

    for k in range(3):
        a = a0 + k * 2 * math.pi / 3 + rng.uniform(-0.2, 0.2)
        e = c + rng.uniform(55, 65) * np.array([math.cos(a), math.sin(a)])
        cv2.line(m, pt(c), pt(e), 1, 3)
        if k > 0:
            cv2.ellipse(m, pt(e), (9, 5), math.degrees(a), 0, 360, 1, -1)
            continue
        for _ in range(6):
            b = a + rng.uniform(-1.2, 1.2)
            f = e + rng.uniform(14, 22) * np.array([math.cos(b), math.sin(b)])
            cv2.line(m, pt(e), pt(f), 1, 2)
            cv2.ellipse(m, pt(f), (7, 4), math.degrees(b), 0, 360, 1, -1)
    return m.astype(bool), c


def test_a_bunch_of_leaf_tips_counts_about_as_one_in_the_tree_median(monkeypatch) -> None:
    """Tree-median tips that lie near each other along the plant share one weight (`TIP_SPREAD`): 12
    drawn plants of three equal stems, one ending in a bunch of six leaves. Measured: median 2.3 px
    from the crown, at most 6.2 px; with every tip counting 1 the bunch pulls the median along its
    stem (median 7.7 px, up to 58 px)."""
    from capm_field import tree_median

    def errors() -> np.ndarray:
        rng = np.random.default_rng(3)
        out = []
        for _ in range(12):
            m, c = _stems_with_a_bunch(rng)
            uv, _, _ = tree_median.tree_median(m)
            out.append(math.hypot(uv[0] - c[0], uv[1] - c[1]))
        return np.array(out)

    e = errors()
    assert np.median(e) < 4.0 and e.max() < 8.0, e.round(1)
    monkeypatch.setattr(tree_median, "TIP_SPREAD", 0.0)
    e = errors()
    assert np.median(e) > 6.0 and e.max() > 30.0, e.round(1)


@pytest.mark.parametrize("seed, i, kind, with_roi", [(3, 57, "purslane", False), (5, 87, "purslane", True),
                                                     (2, 35, "chickweed", True), (3, 34, "seedling", False)])
def test_leaf_bunches_on_stems_do_not_pull_the_crown_of_a_field_photo(seed: int, i: int, kind: str, with_roi: bool,
                                                                      monkeypatch) -> None:
    """Plants of bench/field_photo_weeds.py located by the tree median whose leaves bunch at the ends of
    stems (purslane, chickweed) or whose true leaves crowd one side (a seedling): within 0.15 S of the
    crown (measured 0.02–0.13 S), and > 0.3 S off (in the bunch) when every tip counts 1
    (`TIP_SPREAD` = 0; measured 0.33–0.58 S)."""
    from capm_field import tree_median

    fpw = field_photos()
    img, truth, S, _ = fpw.render(np.random.default_rng([seed, i]), kind)
    roi = fpw.roi_near(seed, i, truth, S) if with_roi else None
    det = detect_centre(img, roi)
    assert crown_off(det, truth, S) < 0.15, det
    monkeypatch.setattr(tree_median, "TIP_SPREAD", 0.0)
    det = detect_centre(img, roi)
    assert det.reason is None and crown_off(det, truth, S) > 0.3, det


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n_blobs=st.integers(1, 4))
def test_candidate_features_on_the_box_crop_equal_those_on_the_whole_grid(seed: int, n_blobs: int) -> None:
    """Stage 1 (`plant_choice.choose`) measures a group of components on the union of their
    boxes, with `origin` its top-left grid cell: every feature must be exactly the one measured
    over the whole grid (the same pixels in the same order)."""
    from capm_field.candidates import candidate_features

    rng = np.random.default_rng(seed)
    h, w = 60, 90
    gm = np.zeros((h, w), bool)
    for _ in range(n_blobs):
        cx, cy, r = rng.integers(5, w - 5), rng.integers(5, h - 5), rng.integers(1, 6)
        gm |= (np.arange(w)[None] - cx) ** 2 + (np.arange(h)[:, None] - cy) ** 2 <= r * r
    vi = rng.normal(0, 0.05, (h, w)).astype(np.float32)
    small = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    gains = np.array([0.9, 1.0, 1.1], np.float32)
    ys, xs = np.nonzero(gm)
    t0, b0, l0, r0 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    args = (gains, -0.02, 0.01, np.array([w / 2, h / 2]), 40.0)
    whole = candidate_features(gm, vi, small, *args)
    crop = candidate_features(gm[t0:b0, l0:r0], vi[t0:b0, l0:r0], small[t0:b0, l0:r0], *args, origin=(int(l0), int(t0)))
    assert crop == whole
    if l0 > 0 or t0 > 0:  # the origin matters: without it the centroid (and so d) moves
        assert candidate_features(gm[t0:b0, l0:r0], vi[t0:b0, l0:r0], small[t0:b0, l0:r0], *args)["d"] != whole["d"]


def test_the_second_looks_plant_replaces_a_first_choice_it_turned_away() -> None:
    """Bench seed 10 case 45: a pale yellow-green seedling that G* does not segment, and farther off a
    small soil-tinted patch that G* takes for a plant (raw G − max(R, B) −0.003). The second look
    (−a*) segments the seedling and turns the patch away (not plant-coloured there), scoring its own
    choice 1.18× the first's: under SMALL_GAIN, but a first choice the second look turned away
    counts for less (REJECTED_GAIN). It was answered on the patch, 209 mm off."""
    case, img, roi = _bench_frame(10, 45, "seedling")
    det = detect_centre(img, roi)
    assert det.reason is None, det
    assert np.linalg.norm(ground_centre(CAM, case.T, det) - case.scene.weeds[0].centre) < 0.015, det
