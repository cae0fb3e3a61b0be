"""How many bench seedling frames the stage-1 score would lose even with perfect masks.

    .venv/bin/python bench/seedling_choice_floor.py --seeds 0-11 [--cases DIR]

The bench (`sim_bench.perception_bench.make_case`) scatters distractor seedlings of 4–12 mm
among weed seedlings of 12–40 mm, and places the weed anywhere in its TROI. For each seedling
frame this takes the scene's true plants, their true leaf area (the parts rasterised at 0.1 mm)
and their distance d from X_w in TROI radii, and scores them as the detector's stage 1 does
(area × exp(−½(d / CENTRAL_SIGMA)²), `capm_field.plant_choice`). "ratio" is the best
distractor's score over the weed's (distractors whose centre lies in the TROI): above 1 no
detector scoring by area and centrality picks the weed even from perfect masks, above
AMBIGUOUS (0.8) it answers "ambiguous" at best. With --cases (a `bench/perception_failures.py
--seeds ...` output directory) each frame's answer there is counted against its ratio.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import cv2
import numpy as np

from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig, TaskConfig
from capm_field.plant_choice import AMBIGUOUS, CENTRAL_SIGMA
from sim_bench.perception_bench import WRONG_MM, bare_cases, make_case

sys.path.insert(0, str(Path(__file__).resolve().parent))
import perception_failures as pf  # noqa: E402  (its --seeds syntax)

RES = 0.0001  # m per raster cell of the leaf area (OpenCV fills the rim cells too: +1.5 % on a 10 mm square)


def leaf_area(plant) -> float:
    """Area (m²) of the union of the plant's parts."""
    x0, y0, x1, y1 = plant.bbox
    m = np.zeros((int((y1 - y0) / RES) + 3, int((x1 - x0) / RES) + 3), np.uint8)
    for part in plant.parts:
        cv2.fillPoly(m, [np.round((part.poly - [x0, y0]) / RES * 16).astype(np.int32)], 1, cv2.LINE_8, shift=4)
    return float(m.sum()) * RES * RES


def frame_ratio(case) -> tuple[float, int]:
    """(best distractor score / weed score, distractors in the TROI) of one seedling case."""
    Xw, r = case.troi_centre, case.troi_radius
    weed = case.scene.weeds[0].plant

    def score(p) -> float:
        d = float(np.linalg.norm(p.centre - Xw)) / r
        return leaf_area(p) * math.exp(-0.5 * (d / CENTRAL_SIGMA) ** 2)

    rivals = [p for p in case.scene.plants
              if p is not weed and p.kind == "seedling" and np.linalg.norm(p.centre - Xw) <= r]
    best = max((score(p) for p in rivals), default=0.0)
    return best / score(weed), len(rivals)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-11")
    ap.add_argument("--scenes", type=int, default=300)
    ap.add_argument("--bare-share", type=float, default=0.15)
    ap.add_argument("--cases", default=None, help="perception_failures.py --seeds output dir (seed_<S>/cases.json)")
    a = ap.parse_args(argv)
    cam = PinholeCamera.from_config(CameraConfig())
    delta = TaskConfig().delta
    rows = []
    for seed in pf._seeds(a.seeds):
        bare = bare_cases(seed, a.scenes, a.bare_share)
        answers = {}
        if a.cases:
            f = Path(a.cases) / f"seed_{seed}" / "cases.json"
            answers = {r["i"]: r for r in json.loads(f.read_text())} if f.exists() else {}
        for i in range(a.scenes):
            if i in bare:
                continue
            case = make_case(seed, i, cam, delta, False)
            if case is None or case.kind != "seedling":
                continue
            ratio, n = frame_ratio(case)
            ans = answers.get(i, {})
            rows.append({"seed": seed, "i": i, "ratio": ratio, "rivals": n, "err_mm": ans.get("err_mm"),
                         "reason": ans.get("reason"), "answered": bool(ans)})
        print(f"seed {seed}: {sum(r['seed'] == seed for r in rows)} seedling frames", file=sys.stderr, flush=True)
    n = len(rows)
    print(f"seedling frames {n}; with a distractor in the TROI {sum(r['rivals'] > 0 for r in rows)}")
    for lo in (0.5, AMBIGUOUS, 1.0):
        sel = [r for r in rows if r["ratio"] > lo]
        line = f"  ratio > {lo:.2f}: {len(sel)} frames ({len(sel) / max(n, 1):.1%})"
        if a.cases:
            wrong = sum(r["err_mm"] is not None and r["err_mm"] > WRONG_MM for r in sel)
            missed = sum(r["answered"] and r["err_mm"] is None for r in sel)
            line += f", of which answered wrong {wrong}, not answered {missed}"
        print(line)
    if a.cases:
        wrong = sorted(r["ratio"] for r in rows if r["err_mm"] is not None and r["err_mm"] > WRONG_MM)
        print(f"wrong answers {len(wrong)}; their ratios: " + ", ".join(f"{x:.2f}" for x in wrong))
    return 0


if __name__ == "__main__":
    sys.exit(main())
