"""Whether stage 2's plant is a lone straight blade: residue (straw, a cut blade), not a weed.

Every weed the detector is for has several parts arranged round its centre: a rosette's leaves,
a seedling's two cotyledons (with a narrow waist between them where their petioles meet), a
grass tuft's fanning blades, a clover's trefoils. One straight piece of even width, widest
near its middle and tapering to both ends, is none of these: it is straw or a cut blade lying on
the soil, which a soil white balance can make as green as a plant. Only for a plant whose colour is
not a green blade's (`candidates.green_blade`, the rule that keeps long green pieces from the
straw rule): a clearly green or teal piece of this shape stays a plant (two narrow teal leaves tip
to tip, whose pinch the resampling nearly fills, tests/test_detector.py). Measured on the stage-2
grid (the plant's box resampled to ~80 px, where the pooling widens thin pieces: a straw of ≥ 8:1
reads ~6:1 there). It also turns away a monocot seedling at its one-leaf stage if it is no greener
than straw (not on the bench; docs/perception.md §4).

Bench seeds 0–11 (session 49), every plant stage 2 looked at: bare-soil straws aspect 6.0–6.7,
fill 0.59–0.71, waist 0.63–0.82; weeds of aspect ≥ 4.5 and fill ≥ 0.45: waist ≤ 0.43.
"""

from __future__ import annotations

import cv2
import numpy as np

BAR_ASPECT = 5.5  # length / width of the plant's minimum-area rectangle from which it may be a bar
BAR_FILL = 0.55  # ... and the plant's share of that rectangle (a straight piece fills it; a bent blade,
# a fan of blades or two crossing ones do not)
BAR_WAIST = 0.6  # ... and the least width in its middle third, × its greatest (two cotyledons in a line
# narrow to their petioles there: ≤ 0.43 measured; a straw stays ≥ 0.63)
BAR_BINS = 12  # width profile: pixel counts in this many slices across the long axis


def lone_bar(xs: np.ndarray, ys: np.ndarray) -> bool:
    """True when the plant's pixels (xs, ys) form one straight piece of even width (see the module)."""
    if len(xs) < 3 * BAR_BINS:
        return False
    pts = np.c_[xs, ys].astype(np.float32)
    (_, (w, h), _) = cv2.minAreaRect(pts)
    long_, short = max(w, h), max(min(w, h), 1.0)
    if long_ / short < BAR_ASPECT or len(xs) < BAR_FILL * long_ * short:
        return False
    d = pts - pts.mean(axis=0)
    _, vecs = np.linalg.eigh(d.T @ d)
    t = d @ vecs[:, 1]  # along the long axis
    widths = np.histogram(t, bins=BAR_BINS, range=(float(t.min()), float(t.max()) + 1e-6))[0]
    third = BAR_BINS // 3
    return float(widths[third:BAR_BINS - third].min()) >= BAR_WAIST * float(widths.max())
