"""Why one bench case was answered as it was: stage 1's candidates and stage 2's estimators, in order.

    .venv/bin/python bench/perception_trace.py --seed 32 235 191 [--all-candidates]

For each case (its cached render, as `bench/perception_failures.py` makes it): the answer, the truth and
the error on the ground; the scored candidates of the look that answered (area on the stage-1 grid, green
mass at full resolution, distance d from X_w in TROI radii, score; `--all-candidates`: also those scoring 0);
then every stage-2 estimator asked, with what it returned, in the order the cascade asked them
(`capm_field.centre_cascade`; an estimator not listed was not reached or not asked).
"""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import perception_failures as pf  # noqa: E402  (the bench's cases and its render cache)

from capm_field import centre_cascade, compound_leaf, fan_apex, hub_petioles, leaf_axes, plant_centre  # noqa: E402
from capm_field import stalks  # noqa: E402
from capm_field.detector import detect_centre, ground_centre, roi_from_troi  # noqa: E402
from sim_bench.perception_bench import bare_cases  # noqa: E402

# (module, function) pairs whose calls are listed; each is looked up where the cascade calls it from
TRACED = [(fan_apex, "fan_apex"), (plant_centre, "petiole_centre"), (plant_centre, "line_hub"),
          (centre_cascade, "stalk_centre"), (compound_leaf, "compound_centre"), (compound_leaf, "has_compound_leaves"),
          (hub_petioles, "hub_petiole_centre"), (plant_centre, "component_median"), (plant_centre, "pair_gap"),
          (leaf_axes, "tip_axes_centre"), (stalks, "has_leaf_clusters")]
CALLS: list[str] = []


def _short(v) -> str:
    if isinstance(v, np.ndarray):
        return np.array2string(np.round(v, 1), separator=", ")
    if isinstance(v, tuple):
        return "(" + ", ".join(_short(x) for x in v) + ")"
    return repr(v)


def _traced(fn, name):
    @functools.wraps(fn)
    def wrapper(*args, **kw):
        out = fn(*args, **kw)
        CALLS.append(f"{name} -> {_short(out)}")
        return out
    return wrapper


def install() -> None:
    """Wrap the traced functions in place (their callers look them up as module attributes)."""
    for mod, name in TRACED:
        if not hasattr(getattr(mod, name), "__wrapped__"):
            setattr(mod, name, _traced(getattr(mod, name), name))


def trace_case(seed: int, i: int, scenes: int, bare_share: float, cache: Path, all_candidates: bool) -> None:
    bare = bare_cases(seed, scenes, bare_share)
    case, img = pf._case_image(seed, i, i in bare, cache)
    if case is None:
        print(f"== seed {seed} case {i}: no NSV pose (not a bench case)")
        return
    roi = roi_from_troi(pf.CAM, case.T, case.troi_centre, case.troi_radius)
    CALLS.clear()
    dbg: dict = {}
    det = detect_centre(img, roi, debug=dbg)
    head = f"== seed {seed} case {i} {case.kind}: {det.reason or 'answer'} {_short(np.array(det.pixel)) if det.pixel else ''}"
    if case.kind != "bare":
        w = case.scene.weeds[0]
        truth = pf.CAM.ground_to_pixel(case.T, w.centre[None])[0]
        g = ground_centre(pf.CAM, case.T, det)
        err = f"{np.linalg.norm(g - w.centre) * 1000:.1f} mm" if g is not None and det.reason is None else "-"
        head += f" truth {_short(truth)} error {err} size {w.plant.extent * 1000:.0f} mm"
    print(head + f" method {dbg.get('method')}")
    for c in dbg.get("cands", []):
        if c.get("score", 0) > 0 or all_candidates:
            print(f"   candidate at {_short(np.array(c['c']))}: area {c['area']:.0f}, mass {c.get('mass_full', 0):.0f}, "
                  f"d {c['d']:.2f}, score {c['score']:.1f}{' (second look)' if c.get('vivid') else ''}")
    for line in CALLS:
        print("   " + line)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", type=int, nargs="+")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scenes", type=int, default=300)
    ap.add_argument("--bare-share", type=float, default=0.15)
    ap.add_argument("--cache", default=None, help="rendered views (default /tmp/pf_cache/<seed>; '{seed}' replaced)")
    ap.add_argument("--all-candidates", action="store_true")
    a = ap.parse_args(argv)
    install()
    cache = pf.cache_dir(a.cache, a.seed, several=False)
    for i in a.cases:
        trace_case(a.seed, i, a.scenes, a.bare_share, cache, a.all_candidates)
    return 0


if __name__ == "__main__":
    sys.exit(main())
