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

Two such pieces crossing in an X (`crossed_bars`: each crossed well inside its length) are straw too:
a plant's parts grow out from its centre and meet at their bases. Blades from one base make a V, a Y
or a T (two opposite blades read as one straight piece through the base: a field-photo grass of three
visible blades was taken for straw when a T counted), and a seedling's cotyledons across its true
leaves make a cross of ovate leaves, whose width is not even along them.

Bench seeds 0–11 (session 49), every plant stage 2 looked at: bare-soil straws aspect 6.0–6.7,
fill 0.59–0.71, waist 0.63–0.82; weeds of aspect ≥ 4.5 and fill ≥ 0.45: waist ≤ 0.43.
"""

from __future__ import annotations

import math

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
    widths = _width_profile(pts)
    third = BAR_BINS // 3
    return float(widths[third:BAR_BINS - third].min()) >= BAR_WAIST * float(widths.max())


def _width_profile(pts: np.ndarray) -> np.ndarray:
    """Pixel counts in BAR_BINS equal slices across the long (principal) axis of the points."""
    d = pts - pts.mean(axis=0)
    _, vecs = np.linalg.eigh(d.T @ d)
    t = d @ vecs[:, 1]  # along the long axis
    return np.histogram(t, bins=BAR_BINS, range=(float(t.min()), float(t.max()) + 1e-6))[0]


WAIST_PIECE = 0.95  # `waisted`: the share of the pixels its largest 8-connected piece must hold


def waisted(xs: np.ndarray, ys: np.ndarray) -> bool:
    """True when the pixels (xs, ys) are two lobes joined by a narrow waist along their long axis:
    one piece (≥ WAIST_PIECE of them 8-connected: not two straws end to end) whose least width in
    the middle third of BAR_BINS slices is < BAR_WAIST × the greatest width of each outer third
    (two cotyledons in a line meeting at their petioles). A straw or a lone leaf is widest in its
    middle, or even along it."""
    if len(xs) < 3 * BAR_BINS:
        return False
    x0, y0 = int(xs.min()), int(ys.min())
    m = np.zeros((int(ys.max()) - y0 + 1, int(xs.max()) - x0 + 1), np.uint8)
    m[ys - y0, xs - x0] = 1
    _, _, st, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if int(st[1:, cv2.CC_STAT_AREA].max()) < WAIST_PIECE * int(m.sum()):
        return False
    widths = _width_profile(np.c_[xs, ys].astype(np.float64))
    third = BAR_BINS // 3
    waist = float(widths[third:BAR_BINS - third].min())
    lobes = min(float(widths[:third].max()), float(widths[BAR_BINS - third:].max()))
    return 0 < waist < BAR_WAIST * lobes


CROSS_COVER = 0.97  # share of the plant's pixels the two bars must hold
CROSS_SECOND = 0.15  # share of them off the first bar from which a second one is looked for
CROSS_ANGLE = math.radians(20.0)  # least angle between them
CROSS_INNER = (0.2, 0.8)  # the joint within this span of each bar's length (an X, not a T, Y or V)
CROSS_GAPS = 2  # empty width slices allowed along a bar (a straw broken in two is still one straw)
CROSS_SEARCH = 256  # the lines are searched among at most ~this many of the pixels (every k-th: bench
# seeds 0-11 gave the same answers as with all of them)
_ANGLES = np.linspace(0.0, np.pi, 90, endpoint=False)  # line directions searched, 2° apart
_COS, _SIN = np.cos(_ANGLES), np.sin(_ANGLES)


def _best_line(x: np.ndarray, y: np.ndarray, half: float, allowed: np.ndarray) -> tuple[int, float]:
    """The line (angle index a, offset ρ: x cos θ_a + y sin θ_a = ρ) whose band of half-width `half`
    holds the most of the points, among the `allowed` angles (a Hough transform of the pixels). The
    band is the bar's own width: a wider one holds the whole bar at a tilt too, and the first of
    those ties would win."""
    step = max(1, len(x) // CROSS_SEARCH)  # (a bar holds its share of every stride of the pixels)
    rho = np.outer(x[::step], _COS) + np.outer(y[::step], _SIN)
    lo = rho.min(axis=0)
    q = np.floor(rho - lo).astype(np.intp)
    w = int(2 * half + 1)
    nb = max(int(q.max()) + 1, w)
    hist = np.bincount((np.arange(len(_ANGLES)) * nb + q).ravel(), minlength=len(_ANGLES) * nb).reshape(-1, nb)
    c = np.concatenate([np.zeros((len(_ANGLES), 1), np.intp), np.cumsum(hist, axis=1)], axis=1)
    win = c[:, w:] - c[:, :-w]  # points in each band of w one-pixel bins
    win[~allowed] = -1
    a, k = np.unravel_index(int(np.argmax(win)), win.shape)
    return int(a), float(lo[a] + k + w / 2.0)


def crossed_bars(xs: np.ndarray, ys: np.ndarray) -> bool:
    """True when the plant's pixels (xs, ys) are two straight pieces of even width that cross in an X
    (each within CROSS_INNER of its length; see the module): the two lines of a Hough transform
    of the pixels hold ≥ CROSS_COVER of them, each piece is ≥ BAR_ASPECT long for its width and away
    from the joint and its tapering ends its width stays ≥ BAR_WAIST of its greatest."""
    n = len(xs)
    if n < 6 * BAR_BINS:
        return False
    x0, y0 = int(xs.min()), int(ys.min())
    m = np.zeros((int(ys.max()) - y0 + 3, int(xs.max()) - x0 + 3), np.uint8)
    m[ys - y0 + 1, xs - x0 + 1] = 1
    h = 2.0 * float(cv2.distanceTransform(m, cv2.DIST_L2, 3)[m > 0].mean())  # a bar's half-width (its
    # distance to the rim rises evenly from it to the middle line)
    if 2.0 * h * BAR_ASPECT > math.hypot(*m.shape):  # too broad for two bars of that aspect: most plants stop here
        return False
    band = h + 1.0  # a pixel's distance from a bar's middle line, at most
    x, y = xs.astype(np.float64), ys.astype(np.float64)
    a1, r1 = _best_line(x, y, h, np.ones(len(_ANGLES), bool))
    in1 = np.abs(x * _COS[a1] + y * _SIN[a1] - r1) <= band
    rest = ~in1
    if np.count_nonzero(rest) < CROSS_SECOND * n:
        return False  # one bar (`lone_bar`'s), or one with a bump
    apart = np.abs((_ANGLES - _ANGLES[a1] + np.pi / 2) % np.pi - np.pi / 2) >= CROSS_ANGLE
    a2, r2 = _best_line(x[rest], y[rest], h, apart)
    in2 = np.abs(x * _COS[a2] + y * _SIN[a2] - r2) <= band
    if np.count_nonzero(in1 | in2) < CROSS_COVER * n:
        return False
    joint = np.linalg.solve(np.array([[_COS[a1], _SIN[a1]], [_COS[a2], _SIN[a2]]]), np.array([r1, r2]))
    for a, on in ((a1, in1), (a2, in2)):
        u = np.array([-_SIN[a], _COS[a]])  # along the bar
        t = x[on] * u[0] + y[on] * u[1]
        tj = float(joint @ u)
        lo, hi = float(t.min()), float(t.max())
        if hi - lo < BAR_ASPECT * 2.0 * h:
            return False
        if not CROSS_INNER[0] <= (tj - lo) / (hi - lo) <= CROSS_INNER[1]:
            return False  # the bars do not cross, or meet at an end (a T, a V: blades from one base)
        edges = np.linspace(lo, hi + 1e-6, BAR_BINS + 1)
        widths = np.histogram(t, bins=edges)[0]
        mid = 0.5 * (edges[:-1] + edges[1:])
        keep = np.abs(mid - tj) > band + 0.5 * (edges[1] - edges[0])  # away from the joint ...
        keep[:2] = keep[-2:] = False  # ... and from the tapering ends
        if np.count_nonzero(widths[2:-2] == 0) > CROSS_GAPS:
            return False
        keep &= widths > 0
        if np.count_nonzero(keep) < 3 or widths[keep].min() < BAR_WAIST * widths[keep].max():
            return False
    return True
