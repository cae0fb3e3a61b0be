"""Grey stones on bare soils of many colours, under colour casts: how often the detector answers a plant.

    .venv/bin/python bench/stones_on_soils.py [--seed 0]

A neutral stone turns green after the detector's soil-referenced white balance when the soil's
green is its weakest channel (purplish or wet red soils) — the same frame is bare soil, so
every answer that is not "no_plant" is a false weed. 12 soil colours × 8 greys × 4 casts
(none, blue shade, green, warm), three stones per frame on Gaussian-textured soil, ROI given.
Prints the count and the frames that answered, by cast (a green cast makes the stones green in
the camera's own colours too: no colour test can tell them from leaves).
"""

from __future__ import annotations

import argparse
import collections
import itertools
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from capm_field.detector import Roi, detect_centre  # noqa: E402

SOILS_BGR = [(80, 90, 150), (60, 80, 140), (70, 95, 160), (90, 100, 130), (60, 70, 110), (50, 60, 90),
             (100, 90, 150), (95, 85, 125), (120, 110, 140), (80, 75, 110), (110, 120, 150), (130, 125, 135)]
STONES_BGR = [(170, 175, 175), (150, 150, 150), (120, 125, 125), (200, 200, 195), (140, 140, 150), (160, 165, 160),
              (110, 110, 110), (185, 180, 180)]
CASTS_BGR = {"none": (1.0, 1.0, 1.0), "blue shade": (1.15, 1.0, 0.9), "green": (0.9, 1.1, 0.95), "warm": (0.85, 1.0, 1.1)}


def frame(rng: np.random.Generator, soil, stone) -> np.ndarray:
    """Textured soil with three stones, float BGR in 0..255 (a cast multiplies it before rounding)."""
    img = cv2.GaussianBlur(rng.normal(0, 12, (480, 640, 3)), (0, 0), 1.0) + soil
    for c in ((300, 200), (360, 260), (250, 300)):
        cv2.circle(img, c, int(rng.integers(8, 20)), stone, -1, cv2.LINE_AA)
    return np.clip(img, 0, 255)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    cv2.setNumThreads(1)
    roi = Roi.from_ellipse((320, 240), (200, 200))
    hits: dict[str, list] = collections.defaultdict(list)
    n = 0
    for (si, soil), (ti, stone) in itertools.product(enumerate(SOILS_BGR), enumerate(STONES_BGR)):
        rng = np.random.default_rng([a.seed, si, ti])
        base = frame(rng, soil, stone)
        for name, cast in CASTS_BGR.items():
            img = np.clip(base * np.asarray(cast), 0, 255).astype(np.uint8)
            n += 1
            if detect_centre(img, roi).reason is None:
                hits[name].append((soil, stone))
    total = sum(len(v) for v in hits.values())
    print(f"{total} of {n} bare-soil frames with grey stones answered a plant")
    for name in CASTS_BGR:
        print(f"  cast {name:10s}: {len(hits[name]):3d} of {n // len(CASTS_BGR)}", *(f"soil {s} stone {t}" for s, t in hits[name][:4]), sep="\n      " if hits[name] else "")
    return 0


if __name__ == "__main__":
    sys.exit(main())
