"""A detector constant A/B over the held-out benches, frame by frame: which answers it moves, and which way.

    .venv/bin/python bench/heldout_pairs.py capm_field.centre_cascade.MIDRIBS=False [--quick]

Each held-out bench's frames are made once and detected twice: as the code stands (A) and with the
constant set as given (B; a module attribute the detector reads at call time):
- `other_renderer_plants.py` seeds 0–2 (n 100), `field_photo_weeds.py` seeds 0–1 (n 160),
  `photo_plants.py` seeds 3–6 (n 70), each frame without and with the bench's own ROI;
- `stones_on_soils.py` seed 0 (384 bare frames: any answer is a false plant).
Errors are in S, the plant's size, as the benches measure them (a miss or a reason counts as ∞).
Printed per bench and kind: frames, B better / worse than A by > TOL S, answers brought within /
taken out of WITHIN S; every frame worse by > TOL is listed (bench, seed, case, kind, ROI, A → B).
`--quick`: one seed of each bench.
"""

from __future__ import annotations

import argparse
import ast
import collections
import importlib
import itertools
import math
import sys
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from capm_field.detector import detect_centre  # noqa: E402

TOL = 0.02  # S: a move smaller than this is neither better nor worse
WITHIN = 0.2  # S: the benches' "within 0.2 S"
SEEDS = {"other_renderer_plants": ((0, 1, 2), 100), "field_photo_weeds": ((0, 1), 160),
         "photo_plants": ((3, 4, 5, 6), 70), "stones_on_soils": ((0,), 0)}
QUICK = {"other_renderer_plants": ((0,), 100), "field_photo_weeds": ((0,), 160),
         "photo_plants": ((3,), 70), "stones_on_soils": ((0,), 0)}


def frames(bench: str, seed: int, n: int) -> Iterator[tuple[int, str, np.ndarray, list, tuple | None, float]]:
    """(case, kind, image, ROIs to try, truth (u, v) or None for bare soil, S) of one bench seed, made as the
    bench makes them."""
    mod = importlib.import_module(bench)
    if bench == "stones_on_soils":
        roi = mod.Roi.from_ellipse((320, 240), (200, 200))
        for k, ((si, soil), (ti, stone)) in enumerate(itertools.product(enumerate(mod.SOILS_BGR), enumerate(mod.STONES_BGR))):
            base = mod.frame(np.random.default_rng([seed, si, ti]), soil, stone)
            for name, cast in mod.CASTS_BGR.items():
                yield k, name, np.clip(base * np.asarray(cast), 0, 255).astype(np.uint8), [roi], None, 1.0
        return
    for i in range(n):
        kind = mod.KINDS[i % len(mod.KINDS)]
        if bench == "field_photo_weeds":
            img, truth, S, _ = mod.render(np.random.default_rng([seed, i]), kind, False, False)
            rois = [None, mod.roi_near(seed, i, truth, S)]
        elif bench == "other_renderer_plants":
            img, truth, S, _ = mod.render(np.random.default_rng([seed, i]), kind)
            r2 = np.random.default_rng([seed, i, 1])  # the bench's --roi ellipse
            r = r2.uniform(1.2, 2.5) * S / 2
            a, o = r2.uniform(0, 2 * math.pi), r2.uniform(0, 0.3 * r)
            rois = [None, ((truth[0] + o * math.cos(a), truth[1] + o * math.sin(a)), (2 * r, 2 * r), 0.0)]
        else:
            case = mod.make_case(seed, i, kind)
            img, truth, S = case["img"], case["truth"], case["S"]
            rois = [None, mod.roi_for(case, seed, i)]
        yield i, kind, img, rois, (float(truth[0]), float(truth[1])), float(S)


def error(img: np.ndarray, roi, truth: tuple | None, S: float) -> float:
    """The answer's error in S (∞ without an answer); for bare soil 0 for no plant, ∞ for an answer."""
    d = detect_centre(img, roi)
    answered = d.reason is None and d.pixel is not None
    if truth is None:
        return math.inf if answered else 0.0
    return math.hypot(d.pixel[0] - truth[0], d.pixel[1] - truth[1]) / S if answered else math.inf


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("setting", help="module.CONSTANT=value (a Python literal), the B side")
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args(argv)
    target, _, value = a.setting.partition("=")
    mod_name, _, const = target.rpartition(".")
    try:
        mod = importlib.import_module(mod_name)
        new = ast.literal_eval(value)
    except (ImportError, ValueError, SyntaxError) as e:
        ap.error(f"{a.setting!r}: {e}")
    if not hasattr(mod, const):
        ap.error(f"{mod_name} has no {const}")
    old = getattr(mod, const)
    cv2.setNumThreads(1)
    total: collections.Counter = collections.Counter()
    for bench, (seeds, n) in (QUICK if a.quick else SEEDS).items():
        tally: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
        for seed in seeds:
            for i, kind, img, rois, truth, S in frames(bench, seed, n):
                for roi in rois:
                    ea = error(img, roi, truth, S)
                    setattr(mod, const, new)
                    try:
                        eb = error(img, roi, truth, S)
                    finally:
                        setattr(mod, const, old)
                    c = tally[kind]
                    c["frames"] += 1
                    c["better"] += eb < ea - TOL
                    c["worse"] += eb > ea + TOL
                    c["brought within"] += ea > WITHIN >= eb
                    c["taken out"] += eb > WITHIN >= ea
                    if eb > ea + TOL:
                        print(f"   worse: {bench} seed {seed} case {i} {kind}{' ROI' if roi is not None else ''}: "
                              f"{ea:.3f} -> {eb:.3f} S", flush=True)
        for kind, c in tally.items():
            print(f"{bench} {kind}: " + ", ".join(f"{k} {v}" for k, v in c.items()), flush=True)
            total.update(c)
    print("all: " + ", ".join(f"{k} {v}" for k, v in total.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
