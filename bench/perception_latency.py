"""The detector's latency over one bench seed's frames, back to back (no render between frames).

    .venv/bin/python bench/perception_latency.py [--seed 0] [--scenes 300] [--profile tottime|cumulative]

The frames are `bench/perception_failures.py`'s cached renders (rendered and cached first where missing,
~0.2 s each), decoded before timing; one thread, as `capm-field bench-perception`. Back to back a frame
costs a few ms less than right after a render (docs/perception.md §3, Latency), so compare code versions
with this, one after the other on the same machine, not across machines or hours. --profile prints
cProfile's 30 largest entries (the profiler's own overhead inflates the times ~1.5×).
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import perception_failures as pf  # noqa: E402  (the bench's cases and its render cache)

from capm_field.detector import detect_centre, roi_from_troi  # noqa: E402
from sim_bench.perception_bench import bare_cases  # noqa: E402


def frames(seed: int, scenes: int, bare_share: float, cache: Path) -> list:
    """(image, roi) of the seed's bench cases, as perception_failures.py makes them."""
    cache.mkdir(parents=True, exist_ok=True)
    bare = bare_cases(seed, scenes, bare_share)
    out = []
    for i in range(scenes):
        case, img = pf._case_image(seed, i, i in bare, cache)
        if case is not None:
            out.append((img, roi_from_troi(pf.CAM, case.T, case.troi_centre, case.troi_radius)))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scenes", type=int, default=300)
    ap.add_argument("--bare-share", type=float, default=0.15)
    ap.add_argument("--cache", default=None, help="rendered views (default /tmp/pf_cache/<seed>, as perception_failures.py)")
    ap.add_argument("--profile", default=None, metavar="SORT", help="cProfile sort key, e.g. tottime or cumulative")
    a = ap.parse_args(argv)
    cv2.setNumThreads(1)
    cache = Path(a.cache) if a.cache else Path(f"/tmp/pf_cache/{a.seed}")
    fr = frames(a.seed, a.scenes, a.bare_share, cache)
    for img, roi in fr[:5]:  # warm-up: numba's compiled loops, OpenCV's first calls
        detect_centre(img, roi)
    prof = cProfile.Profile() if a.profile else None
    lat = []
    for img, roi in fr:
        if prof:
            prof.enable()
        t0 = time.perf_counter()
        detect_centre(img, roi)
        lat.append((time.perf_counter() - t0) * 1000)
        if prof:
            prof.disable()
    print(f"seed {a.seed}: {len(lat)} frames, latency median {np.median(lat):.2f} ms, mean {np.mean(lat):.2f} ms, "
          f"p90 {np.percentile(lat, 90):.2f} ms (back to back, 1 thread{', under cProfile' if prof else ''})")
    if prof:
        pstats.Stats(prof).sort_stats(a.profile).print_stats(30)
    return 0


if __name__ == "__main__":
    sys.exit(main())
