"""At which stage the detector lost each failing bench weed frame (a miss or a centre > 30 mm off).

    .venv/bin/python bench/perception_failure_stages.py --cases DIR [--list] [--json FILE]

DIR is a `bench/perception_failures.py --seeds ...` output (DIR/seed_<S>/cases.json; the renders
from its cache, default /tmp/pf_cache/<seed>). Each failing weed frame is detected again with
today's code and put in the furthest stage it reached:

  not_segmented  no stage-1 component of either look whose centroid lies on the weed
  turned_away    components on the weed, none kept: the colour or straw rules dropped them
  not_scored     kept components on the weed, but no candidate on it scored (grouping, size,
                 elongation, the TROI gate)
  outscored      a candidate on the weed scored; another plant was answered, or "ambiguous"
  stage2         the answer is on the weed (its hull) but > 30 mm from its centre (or cut_by_border), or
                 "no_plant" although a candidate on the weed scored (stage 2 declined it)
  right_now      today's answer is right (the run in DIR was made with other code)

"Either look" is what the detector's debug shows: a second look after a small, pale or faint first
choice is listed only when it was taken. The figures bound what a fix at one stage can give:
a perfect colour rule, say, recovers the `turned_away` frames at most.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import perception_failures as pf  # noqa: E402  (the bench's cases and its render cache)
from perception_compare import load  # noqa: E402  (a --seeds run's cases.json per seed)

from capm_field.detector import detect_centre, ground_centre, roi_from_troi  # noqa: E402
from sim_bench.perception_bench import WRONG_MM  # noqa: E402

STAGES = ("not_segmented", "turned_away", "not_scored", "outscored", "stage2", "right_now")
ON_WEED_PX = 3  # a point "on the weed": on its image mask dilated by this many pixels (rendering, resampling)


def weed_mask(camera, T, plant, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The plant's parts projected into the image, and their convex hull (bool H×W each, grown by
    ON_WEED_PX): where the weed is as rendered, and the plant with the soil between its leaves."""
    m = np.zeros(shape, np.uint8)
    pts = []
    for part in plant.parts:
        px = camera.ground_to_pixel(T, np.asarray(part.poly, float))
        if np.all(np.isfinite(px)):
            pts.append(px)
            cv2.fillPoly(m, [np.round(px * 16).astype(np.int32)], 1, cv2.LINE_8, shift=4)
    hull = np.zeros(shape, np.uint8)
    if pts:
        h = cv2.convexHull(np.round(np.concatenate(pts) * 16).astype(np.int32))
        cv2.fillPoly(hull, [h], 1, cv2.LINE_8, shift=4)
    k = np.ones((2 * ON_WEED_PX + 1,) * 2, np.uint8)
    return cv2.dilate(m, k) > 0, cv2.dilate(hull, k) > 0


def _on(mask: np.ndarray, p) -> bool:
    u, v = int(round(p[0])), int(round(p[1]))
    return 0 <= v < mask.shape[0] and 0 <= u < mask.shape[1] and bool(mask[v, u])


def classify(weed: np.ndarray, hull: np.ndarray, truth_px, reason: str | None, pixel, err_mm: float | None,
             debug: dict) -> str:
    """The furthest stage (one of STAGES) a weed frame reached.

    weed, hull: the weed's image mask and its hull (`weed_mask`); truth_px: its true centre in the
    image; reason, pixel: the Detection's; err_mm: the answer's error on the ground (None without an
    answer); debug: `detect_centre`'s debug dict ("comps": every stage-1 component with its
    "c"entroid and "ok"; "cands": the grouped candidates with their centroid "c", box "bb" and
    "score"). A component is on the weed if its centroid is on the mask; a candidate also if its box
    holds the true centre (a clover's trefoils round a bare middle)."""
    if reason is None and err_mm is not None and err_mm <= WRONG_MM:
        return "right_now"
    if pixel is not None and reason in (None, "cut_by_border") and _on(hull, pixel):
        return "stage2"  # the weed was located, its centre missed
    t = truth_px
    weed_scored = any(c.get("score", 0) > 0 and (_on(weed, c["c"]) or c["bb"][0] <= t[0] <= c["bb"][2]
                                                   and c["bb"][1] <= t[1] <= c["bb"][3])
                      for c in debug.get("cands", []))
    if weed_scored:
        # the weed scored: "no_plant" then is stage 2 declining the chosen plant (straw shape)
        return "stage2" if reason == "no_plant" else "outscored"
    near = [c for c in debug.get("comps", []) if _on(weed, c["c"])]
    if not near:
        return "not_segmented"
    if not any(c.get("ok") for c in near):
        return "turned_away"
    return "not_scored"


def stage_of_case(seed: int, row: dict, cache: Path) -> dict:
    """Detect one failing case of `cases.json` again and classify it."""
    case, img = pf._case_image(seed, row["i"], False, cache)
    roi = roi_from_troi(pf.CAM, case.T, case.troi_centre, case.troi_radius)
    dbg: dict = {}
    det = detect_centre(img, roi, debug=dbg)
    w = case.scene.weeds[0]
    g = ground_centre(pf.CAM, case.T, det)
    err = float(np.linalg.norm(g - w.centre) * 1000) if g is not None and det.pixel is not None else None
    truth = pf.CAM.ground_to_pixel(case.T, w.centre[None])[0]
    stage = classify(*weed_mask(pf.CAM, case.T, w.plant, img.shape[:2]), truth, det.reason, det.pixel, err, dbg)
    return dict(seed=seed, i=row["i"], kind=row["kind"], reason=det.reason, err_mm=err, method=dbg.get("method"),
                stage=stage)


def run(cases_dir: Path, cache: str | None) -> list[dict]:
    out = []
    runs = load(cases_dir)
    if not runs and (cases_dir / "cases.json").exists():
        raise SystemExit(f"{cases_dir}: a single-seed run; give the --seeds run's directory (seed_<S>/cases.json)")
    for seed in sorted(runs):
        rows = [r for r in runs[seed] if r["kind"] != "bare" and r.get("fail")]
        renders = pf.cache_dir(cache, seed, several=True)
        out += [stage_of_case(seed, r, renders) for r in rows]
        print(f"seed {seed}: {len(rows)} failing weed frames", file=sys.stderr, flush=True)
    return out


def table(rows: list[dict]) -> str:
    kinds = sorted({r["kind"] for r in rows})
    count = Counter((r["kind"], r["stage"]) for r in rows)
    lines = [f"{'kind':<10}" + "".join(f"{s:>15}" for s in STAGES) + f"{'all':>7}"]
    for k in kinds + ["all"]:
        n = [sum(v for (kk, s), v in count.items() if s == st and (k == "all" or kk == k)) for st in STAGES]
        lines.append(f"{k:<10}" + "".join(f"{v:>15}" for v in n) + f"{sum(n):>7}")
    lines.append("of them wrong answers (> 30 mm): " + ", ".join(
        f"{s} {sum(1 for r in rows if r['stage'] == s and r['reason'] is None)}" for s in STAGES[:-1]))
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", required=True, type=Path, help="a perception_failures.py --seeds output directory")
    ap.add_argument("--cache", default=None, help="rendered views, as perception_failures.py --seeds takes it "
                    "('{seed}' replaced, else one subdirectory per seed; default /tmp/pf_cache/<seed>)")
    ap.add_argument("--list", action="store_true", help="one line per failing frame")
    ap.add_argument("--json", type=Path, help="write the per-frame stages here")
    a = ap.parse_args(argv)
    if not a.cases.is_dir():
        ap.error(f"{a.cases}: not a directory")
    cv2.setNumThreads(1)
    rows = run(a.cases, a.cache)
    if not rows:
        print(f"no failing weed frames under {a.cases} (seed_*/cases.json)")
        return 0
    if a.list:
        for r in rows:
            e = f"{r['err_mm']:.1f} mm" if r["err_mm"] is not None else "-"
            print(f"seed {r['seed']} case {r['i']} {r['kind']}: {r['stage']} ({r['reason'] or 'answer'} {e}, "
                  f"{r['method']})")
    print(table(rows))
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
