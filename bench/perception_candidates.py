"""Candidate-plant features on the bench cases (analysis for the detector's candidate rules).

    .venv/bin/python bench/perception_candidates.py --scenes 300 --seed 0 [--cache /tmp/pf_cache/0]

For every case, the detector's candidate plants (debug["cands"]) are labelled true (the weed's
true centre lies in the candidate's box grown by 20 %) or false, and written to candidates.json.
Needs the render cache of bench/perception_failures.py.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from perception_failures import CAM, _case_image  # noqa: E402

from capm_field.detector import detect_centre, roi_from_troi  # noqa: E402
from sim_bench.perception_bench import bare_cases  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache", default=None)
    ap.add_argument("--out", default="/tmp/candidates.json")
    a = ap.parse_args(argv)
    cv2.setNumThreads(1)
    cache = Path(a.cache or f"/tmp/pf_cache/{a.seed}")
    cache.mkdir(parents=True, exist_ok=True)
    bare_idx = bare_cases(a.seed, a.scenes, 0.15)
    rows = []
    for i in range(a.scenes):
        case, img = _case_image(a.seed, i, i in bare_idx, cache)
        if case is None:
            continue
        dbg: dict = {}
        detect_centre(img, roi_from_troi(CAM, case.T, case.troi_centre, case.troi_radius), debug=dbg)
        t = None if case.kind == "bare" else CAM.ground_to_pixel(case.T, case.scene.weeds[0].centre[None])[0]
        for c in dbg.get("cands", []):
            x0, y0, x1, y1 = c["bb"]
            mx, my = 0.2 * (x1 - x0) + 3, 0.2 * (y1 - y0) + 3
            c["true"] = bool(t is not None and x0 - mx <= t[0] <= x1 + mx and y0 - my <= t[1] <= y1 + my)
            c["i"], c["kind"] = i, case.kind
            rows.append(c)
    Path(a.out).write_text(json.dumps(rows))
    print(len(rows), "candidates")
    return 0


if __name__ == "__main__":
    sys.exit(main())
