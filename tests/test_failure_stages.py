"""bench/perception_failure_stages.py: each failing bench frame put in the stage that lost it."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
import perception_failure_stages as fs  # noqa: E402


def _masks():
    """A weed of two leaves (pixels 40–59 × 40–49 and 70–89 × 40–49) with a bare middle; its hull spans both."""
    weed = np.zeros((120, 160), bool)
    weed[40:50, 40:60] = weed[40:50, 70:90] = True
    hull = np.zeros_like(weed)
    hull[40:50, 40:90] = True
    return weed, hull


def _comp(c, ok):
    return {"c": list(c), "ok": ok}


def _cand(c, score, bb=None):
    return {"c": list(c), "score": score, "bb": list(bb or (c[0] - 5, c[1] - 5, c[0] + 5, c[1] + 5))}


T = (65.0, 45.0)  # the true centre, between the leaves


def test_each_stage_from_the_debug_record():
    weed, hull = _masks()
    other = (140.0, 100.0)  # another plant, off the weed
    assert fs.classify(weed, hull, T, None, (66, 45), 4.0, {}) == "right_now"
    # answered within the hull (between the leaves) but far from the centre on the ground: stage 2
    assert fs.classify(weed, hull, T, None, (62, 45), 35.0, {"cands": [_cand(other, 9)]}) == "stage2"
    assert fs.classify(weed, hull, T, "cut_by_border", (45, 45), None, {}) == "stage2"
    # a candidate on the weed scored, another plant answered or a tie: outscored
    dbg = {"comps": [_comp((50, 45), True), _comp(other, True)], "cands": [_cand((50, 45), 5), _cand(other, 9)]}
    assert fs.classify(weed, hull, T, None, other, 150.0, dbg) == "outscored"
    assert fs.classify(weed, hull, T, "ambiguous", other, None, dbg) == "outscored"
    # ... and "no_plant" with the weed scored is stage 2 declining it
    assert fs.classify(weed, hull, T, "no_plant", None, None, dbg) == "stage2"
    # a group whose centroid is in the bare middle still counts when its box holds the true centre
    mid = {"cands": [_cand((65, 45), 5, (40, 40, 89, 49))], "comps": []}
    assert fs.classify(weed, hull, T, "ambiguous", other, None, mid) == "outscored"
    # kept component on the weed, no candidate on it scored
    dbg = {"comps": [_comp((80, 44), True)], "cands": [_cand((80, 44), 0.0), _cand(other, 9)]}
    assert fs.classify(weed, hull, T, None, other, 150.0, dbg) == "not_scored"
    # components on the weed, all dropped by the colour rules
    dbg = {"comps": [_comp((80, 44), False), _comp(other, True)], "cands": [_cand(other, 9)]}
    assert fs.classify(weed, hull, T, None, other, 150.0, dbg) == "turned_away"
    # nothing on the weed: a component in its bare middle is not on it
    dbg = {"comps": [_comp((65, 45), True), _comp(other, True)], "cands": [_cand(other, 9)]}
    assert fs.classify(weed, hull, T, "no_plant", None, None, {"comps": []}) == "not_segmented"
    assert fs.classify(weed, hull, T, None, other, 150.0, dbg) == "not_segmented"


def test_weed_mask_of_a_rendered_case_covers_its_leaves_and_hull(tmp_path):
    import perception_failures as pf

    case, img = pf._case_image(0, 0, False, tmp_path)  # seed 0 case 0: a rosette
    w = case.scene.weeds[0]
    weed, hull = fs.weed_mask(pf.CAM, case.T, w.plant, img.shape[:2])
    assert weed.shape == img.shape[:2] and weed.any()
    assert not (weed & ~hull).any() and hull.sum() >= weed.sum()
    tips = np.array([p.tip for p in w.plant.parts])
    px = np.round(pf.CAM.ground_to_pixel(case.T, tips)).astype(int)
    assert all(weed[v, u] for u, v in px if 0 <= v < img.shape[0] and 0 <= u < img.shape[1])
    assert weed.mean() < 0.5  # the plant, not the frame


def test_cli_reruns_the_failing_rows(tmp_path):
    """A row marked failing that today's detector answers right is `right_now`; bare rows are skipped."""
    d = tmp_path / "run" / "seed_0"
    d.mkdir(parents=True)
    rows = [{"i": 0, "kind": "rosette", "fail": True, "reason": "no_plant", "err_mm": None},
            {"i": 1, "kind": "bare", "fail": True, "reason": None, "err_mm": None}]
    (d / "cases.json").write_text(json.dumps(rows))
    out = subprocess.run([sys.executable, str(ROOT / "bench" / "perception_failure_stages.py"), "--cases",
                          str(tmp_path / "run"), "--cache", str(tmp_path / "cache"), "--list", "--json",
                          str(tmp_path / "s.json")], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    got = json.loads((tmp_path / "s.json").read_text())
    assert [(r["i"], r["stage"]) for r in got] == [(0, "right_now")]
    assert (tmp_path / "cache" / "0" / "00000.png").exists()  # a shared --cache: one subdirectory per seed
    assert "seed 0 case 0 rosette: right_now" in out.stdout
    all_row = next(line for line in out.stdout.splitlines() if line.startswith("all "))
    assert all_row.split()[1:] == ["0", "0", "0", "0", "0", "1", "1"]  # the stages in STAGES order, then all
    none = subprocess.run([sys.executable, str(ROOT / "bench" / "perception_failure_stages.py"), "--cases",
                           str(tmp_path / "missing")], capture_output=True, text=True, timeout=60)
    assert none.returncode == 2 and "not a directory" in none.stderr


def test_cache_dir_as_perception_failures_takes_it(tmp_path):
    import perception_failures as pf

    shared = str(tmp_path / "views")
    assert pf.cache_dir(shared, 3, several=True) == tmp_path / "views" / "3"  # seeds' views named alike: apart
    assert pf.cache_dir(shared, 3, several=False) == tmp_path / "views"
    assert pf.cache_dir(shared + "_{seed}", 4, several=True) == tmp_path / "views_4"
    assert (tmp_path / "views" / "3").is_dir() and (tmp_path / "views_4").is_dir()
