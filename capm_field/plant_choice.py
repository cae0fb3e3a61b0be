"""Stage 1 of one look of the weed-centre detector: which plant in the search window.

The window's vegetation index (G*, or CIELAB −a* in the vivid second look) max-pooled onto the
stage-1 grid, thresholded with hysteresis; components judged by their own colour (stones,
straw, soil tints dropped; a plant touching a stone split off by its green part), grouped into
plants and scored by green mass at full resolution × centrality in the TROI (`choose`).
`capm_field.detector` then locates the best one's centre, or answers "ambiguous" when a
runner-up scores within AMBIGUOUS of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from . import straw_shape
from .candidates import (LC_RING, STRAW_ELONG, STRAW_ELONG_FULL, STRAW_RAW, candidate_features, contrast_band,
                         green_blade, plant_like)
from .components import components
from .detection import Detection
from .order_stats import elongation, median, percentile
from .search_window import MID_PX_STAGE1, SearchWindow
from .vegetation import cap_clipped, pooled_index, vegetation_index
from .vegetation_mask import group_box, group_components, hysteresis, threshold

AMBIGUOUS = 0.8  # runner-up score / best score above which the choice is "ambiguous" (see `capm_field.detector`)


@dataclass
class Choice:
    """A look's plants, scored, before the centre of the best is sought (see `choose`)."""

    vivid: bool
    gains: np.ndarray  # white balance of this look
    thr: float  # index threshold and soil level of this look
    soil_level: float
    contrast: float
    lab: np.ndarray  # component labels on the stage-1 grid
    scored: list  # (score, stage-1 mask, area, full-image box or None, features), best first

    @property
    def best(self) -> float:
        return self.scored[0][0]


def choose(img: np.ndarray, win: SearchWindow, vivid: bool = False, debug: dict | None = None,
           first: dict | None = None) -> Choice | Detection:
    """Stage 1 of one look: the vegetation mask of the window, its candidate plants judged and
    scored (green mass × centrality). Detection "no_plant" when there is none; `first` as in
    `capm_field.detector._detect`."""
    roi, x0, y0 = win.roi, win.x0, win.y0
    mid, small, sx, sy, inside, n_in = win.mid, win.small, win.sx, win.sy, win.inside, win.n_in

    to_full = win.to_full  # window pixel (i, j) of `small` → full image

    # ---- vegetation mask
    gains = win.gains ** VIVID_WB if vivid else win.gains
    vi = pooled_index(mid, gains, (small.shape[1], small.shape[0]), MID_PX_STAGE1, lab=vivid, cap=win.overexposed)
    # soil statistics from every other row and column: the same percentiles in a quarter of the time
    at = inside if win.soil is None else win.soil
    n_at = n_in if win.soil is None else int(np.count_nonzero(at))
    thr, soil_level, contrast = threshold(vi[::2, ::2][at[::2, ::2]] if n_at >= 4096 else vi[at])
    mask = hysteresis(vi, thr, soil_level, inside)
    n, lab, stats, cents = components(mask)
    min_area = max(6.0, 1.5e-4 * n_in)
    comps = [k for k in range(1, n) if stats[k, cv2.CC_STAT_AREA] >= min_area]
    if not comps:
        return Detection(None, 0.0, "no_plant")
    # soil spread of the index outside the vegetation mask (robust: median → p90)
    soil_px = vi[::2, ::2][(at & ~mask)[::2, ::2]] if n_at >= 4096 else vi[at & ~mask]
    sig = max((percentile(soil_px, 90) - soil_level) / 1.28, 1e-3) if soil_px.size >= 16 else 0.01
    # ROI centre and radius on the stage-1 grid (candidate centrality)
    if roi is not None:
        rc, rax, _ = roi.params()
        cen_s = np.array([(rc[0] - x0 + 0.5) / sx - 0.5, (rc[1] - y0 + 0.5) / sy - 0.5])
        rad_s = float(np.sqrt(rax[0] * rax[1]) / math.sqrt(sx * sy))
    else:
        cen_s = np.array([(small.shape[1] - 1) / 2, (small.shape[0] - 1) / 2])
        rad_s = 0.5 * math.hypot(*small.shape[:2])
    # components whose own colour is not a plant's (straw, stones) are not grouped with plants
    keep = []
    feats: dict[int, dict] = {}  # per component: also the features of a group of that one component

    def measure(m: np.ndarray, l0: int, t0: int) -> dict:  # features of a mask cropped from grid (l0, t0)
        h0, w0 = m.shape
        f = candidate_features(m, vi[t0:t0 + h0, l0:l0 + w0], small[t0:t0 + h0, l0:l0 + w0], gains, soil_level, sig,
                               cen_s, rad_s, origin=(l0, t0))
        f["area_frac"] = f["area"] / n_in
        return f

    for k in comps:
        l0, t0, w0, h0 = (int(v) for v in stats[k, :4])
        sub = lab[t0:t0 + h0, l0:l0 + w0] == k
        f = measure(sub, l0, t0)
        if vivid and contrast_band(f):
            f["lc"], f["core"] = _local_contrast(img, sub, (l0, t0), win, gains, thr, soil_level)
        ok = _kept(f, vivid)
        if not ok and not vivid and SPLIT_GREEN and stats[k, cv2.CC_STAT_AREA] >= SPLIT_MIN * min_area:
            # a plant touching a larger stone (or straw) that the white balance made as green: one
            # component, of the stone's median colour. Its green part alone, if that is clearly a
            # plant, stays as this component (first look only: in −a* the part taken from soil
            # tints and straw made distractor seedlings outscore the weed)
            part = _green_part(sub, small[t0:t0 + h0, l0:l0 + w0], min_area)
            f2 = measure(part, l0, t0) if part is not None else None
            if f2 is not None and _kept(f2, False) and _clearly_green(f2):
                lab[t0:t0 + h0, l0:l0 + w0][sub & ~part] = 0
                py, px = np.nonzero(part)
                stats[k, cv2.CC_STAT_AREA] = len(px)  # (its box stays: a superset, for grouping)
                cents[k] = (l0 + px.mean(), t0 + py.mean())
                f, ok = f2, True
        feats[k] = dict(f)
        if ok:
            keep.append(k)
        elif vivid and first is not None:  # the boxes of the components the second look turned away (read
            # by `detector._looks` only for that look: the first look does not make them)
            first.setdefault("rejected", []).append(mask_box(np.array([l0, l0 + w0 - 1]), np.array([t0, t0 + h0 - 1]),
                                                             to_full))
        if debug is not None:  # every component's colour features and full-image centroid
            f.update(ok=ok, vivid=vivid, c=[float(v) for v in to_full(cents[k])])
            debug.setdefault("comps", []).append(f)
    comps = keep
    if not comps:
        return Detection(None, 0.0, "no_plant")

    # ---- plants: group components, score by size and centrality
    groups = group_components(lab, stats, comps)
    rim = inside & ~cv2.erode(inside.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) if roi is not None else np.zeros_like(inside)
    scored = []
    for g in groups:
        if debug is None and int(stats[g, cv2.CC_STAT_AREA].sum()) < (VIVID_AREA if vivid else 1.5) * min_area:
            continue  # too small to be chosen: no features needed
        # the group's mask is made and read within the union of its components' boxes only (the
        # same pixels in the same order as over the whole grid: the same values, ~0.5 ms less a frame)
        l0, t0, r0, b0 = group_box(stats, g)
        local = lab[t0:b0, l0:r0] == g[0] if len(g) == 1 else np.isin(lab[t0:b0, l0:r0], g)
        gm = np.zeros(lab.shape, bool)
        gm[t0:b0, l0:r0] = local
        if len(g) == 1:  # the component's own features (same pixels in the same order: same values)
            f = dict(feats[g[0]])
        else:
            f = candidate_features(local, vi[t0:b0, l0:r0], small[t0:b0, l0:r0], gains, soil_level, sig, cen_s, rad_s,
                                   origin=(l0, t0))
            if vivid and contrast_band(f):
                gy, gx = np.nonzero(local)
                by, bx = int(gy.min()), int(gx.min())
                f["lc"], f["core"] = _local_contrast(img, local[by:gy.max() + 1, bx:gx.max() + 1], (l0 + bx, t0 + by), win,
                                                     gains, thr, soil_level)
        f["area_frac"] = f["area"] / n_in
        box = None  # full-image box of a candidate with a positive score, for "contenders"
        f["ok"] = bool(f["area"] >= (VIVID_AREA if vivid else 1.5) * min_area and plant_like(f, vivid)
                       and (f["elong"] <= STRAW_ELONG or green_blade(f)))
        if f["ok"]:
            # green mass measured at full resolution (the stage-1 max-pooling inflates small
            # objects), × a mild pull towards the TROI centre (the prescan's estimate), ÷ 3 for a
            # candidate cut by the ROI margin (an object reaching in from outside the TROI)
            ys, xs = np.nonzero(local)
            xs += l0
            ys += t0
            fx0, fy0, fx1, fy1 = mask_box(xs, ys, to_full)
            sub = img[max(int(fy0), 0):int(math.ceil(fy1)) + 1, max(int(fx0), 0):int(math.ceil(fx1)) + 1]
            vf = vegetation_index(sub, gains=gains, lab=vivid)
            if win.overexposed:
                cap_clipped(sub, vf, soil_level)
            mf = vf > 0.5 * (thr + soil_level)
            f["mass_full"] = float(np.count_nonzero(mf)) / (sx * sy)
            yy, xx = np.nonzero(mf)
            if len(xx) >= 3:
                f["elong_full"] = elongation(xx, yy)
            else:
                f["elong_full"] = 1.0
            cut = bool(np.any(local & rim[t0:b0, l0:r0]))
            cf = to_full(np.array([xs.mean(), ys.mean()]))  # centroid in the full image
            g = roi.on_ground(cf) if roi is not None else None
            if g is not None:  # distance from X_w and green area on the ground (in X_w's pixels), not in the image
                f["d"], f["mass_full"] = g[0], f["mass_full"] * g[1]
            f["score"] = f["mass_full"] * math.exp(-0.5 * (f["d"] / CENTRAL_SIGMA) ** 2) * (0.33 if cut else 1.0)
            # a straight thin piece at full resolution is straw, not a weed (measured: weeds ≤ 4.5), unless it
            # narrows to a waist between two lobes (two cotyledons in a line)
            if f["elong_full"] > STRAW_ELONG_FULL and not green_blade(f) \
                    and not (WAISTED_PAIR and straw_shape.waisted(xx, yy)):
                f["score"] = 0.0
            # the TROI holds the weed's centre (the margin is for overhanging leaves only)
            if roi is not None and not roi.contains(cf[None], 1.0)[0]:
                f["score"] = 0.0
            if f["score"] > 0 and first is not None:
                box = (fx0, fy0, fx1, fy1)
        else:
            f["score"] = 0.0
        scored.append((f["score"], gm, f["area"], box, f))
        if debug is not None:
            ys, xs = np.nonzero(gm)
            f["c"] = [float(c) for c in to_full(np.array([xs.mean(), ys.mean()]))]
            f["bb"] = list(mask_box(xs, ys, to_full))
            f.update(sig=sig, thr=thr - soil_level, soil=soil_level)
            debug.setdefault("cands", []).append(f)
    if not scored:
        return Detection(None, 0.0, "no_plant")
    scored.sort(key=lambda t: -t[0])
    best_score, best_f = scored[0][0], scored[0][4]
    if first is not None:
        first["contenders"] = [t[3] for t in scored if t[3] is not None and t[0] >= AMBIGUOUS * best_score]
        first["best"] = best_score  # vegetation area × centrality (see above), stage-1 pixels
        first["feat"] = best_f
        first["box"] = scored[0][3]  # the chosen plant's full-image box (None if its score is 0)
    return Choice(vivid, gains, thr, soil_level, contrast, lab, scored)


SPLIT_GREEN = True  # first look: a dropped component's green part is judged on its own (`_green_part`)
SPLIT_MIN = 2.0  # × the minimum component area: smaller dropped components are not split
SPLIT_GM = 0.05  # pixel (G − (R + B)/2)/(R + G + B + 30) before the white balance from which it is green
SPLIT_SHARE, SPLIT_REST = 0.15, 0.3  # the green part: ≥ this share of the component, leaving ≥ this share
SPLIT_RAW, SPLIT_GM_MED, SPLIT_SAT_RAW = 0.01, 0.08, 0.23  # and beyond `plant_like`, clearly green in the camera's
# colours: g_raw, gm_raw and sat_raw medians ≥ these. Measured (session 22): other renderer no ROI seeds 0–2
# found 91/92/90 → 92/92/92 % (a rosette touching a larger pale stone on dark red soil: no_plant → 0.18 S);
# bench seeds 0–7, photo-like seeds 3–6, stones_on_soils.py (31 of 384) and 200 fresh bare scenes (196)
# unchanged but two grass answers (23.1 → 21.6, 2.9 → 6.7 mm). Looser (pixel 0.03, no raw clauses, no
# SPLIT_REST, both looks): other renderer +7 found, but 2 bench bare-soil frames answered a plant (soil
# tints: the greenest pixels of any patch pass the colour rules), a grass blade with a seedling became a
# plant (seed 3 case 37: 1.6 → 260 mm) and, in −a*, an ambiguous seedling a wrong one (seed 4 case 117).
# Pale blue-green plants (gm_raw 0.05–0.06 when split) stay out: bare soil tints measured the same


def _kept(f: dict, vivid: bool) -> bool:
    """Whether a stage-1 component stays (may be grouped with others): plant-coloured, and not a
    long straight piece whose raw colour is not green (straw that the soil white balance turned
    green would drag a plant's centre it joined)."""
    return plant_like(f, vivid) and not (f["elong"] > STRAW_ELONG and f["g_raw"] < STRAW_RAW)


def _clearly_green(f: dict) -> bool:
    """A split-off green part's colour in the camera's own colours (SPLIT_RAW, SPLIT_GM_MED, SPLIT_SAT_RAW)."""
    return f["g_raw"] >= SPLIT_RAW and f["gm_raw"] >= SPLIT_GM_MED and f["sat_raw"] >= SPLIT_SAT_RAW


def _green_part(sub: np.ndarray, bgr: np.ndarray, min_area: float) -> np.ndarray | None:
    """The largest connected part of a stage-1 candidate mask `sub` whose pixels are green above
    magenta in the camera's own colours ((G − (R + B)/2)/(R + G + B + 30) ≥ SPLIT_GM; `bgr`: the
    stage-1 colours under `sub`), if it is ≥ min_area and ≥ SPLIT_SHARE of the candidate and
    leaves ≥ SPLIT_REST of it (a second material, not the plant's own rim); else None."""
    b, g, r = cv2.split(bgr.astype(np.float32))
    gm = (g - 0.5 * (b + r)) / (b + g + r + 30)
    green = sub & (gm >= SPLIT_GM)
    n_sub = int(np.count_nonzero(sub))
    n, lab2, st2, _ = components(green)
    if n <= 1:
        return None
    c = 1 + int(np.argmax(st2[1:, cv2.CC_STAT_AREA]))
    a = int(st2[c, cv2.CC_STAT_AREA])
    if a < min_area or a < SPLIT_SHARE * n_sub or a > (1 - SPLIT_REST) * n_sub:
        return None
    return lab2 == c


# ---- pieces ------------------------------------------------------------------------------------
def mask_box(xs: np.ndarray, ys: np.ndarray, to_full) -> tuple[float, float, float, float]:
    """Full-image box (x0, y0, x1, y1) of stage-1 grid pixels (xs, ys)."""
    fx0, fy0 = to_full(np.array([xs.min() - 0.5, ys.min() - 0.5]))
    fx1, fy1 = to_full(np.array([xs.max() + 0.5, ys.max() + 0.5]))
    return float(fx0), float(fy0), float(fx1), float(fy1)


WAISTED_PAIR = True  # the full-resolution straw rule (elongation > STRAW_ELONG_FULL, not a green blade's
# colour) spares one piece narrowed to a waist between two lobes (`straw_shape.waisted`): two cotyledons in a line,
# whose petioles meet there; straw is widest in its middle or even. Session 74, bench seeds 0–11: detected 2 998 →
# 3 000 (two seedlings, 1.8 and 0.8 mm), nothing else moved; seeds 30–37 and 600 fresh bare frames (seeds 40–41,
# bare share 1.0) unchanged
CENTRAL_SIGMA = 0.8  # of the ROI radius: how fast the candidate score falls off from the TROI centre
VIVID_WB = 0.5  # exponent on the soil white balance in the second look: half (a full pull towards a reddish
# soil turns yellow-green leaves on grey-olive soil orange; none measured 0.4 % fewer detections)
VIVID_AREA = 3.0  # × the minimum component area (a 20-px green speck on bare soil came up; 4.0 until
# session 13: bench seed 1 case 1, a seedling of 41 stage-1 px under 4 × 11.8, lost to a distractor 63 mm away; 3.0 moved
# no bench bare-soil frame, none of 200 fresh bare scenes or bench/stones_on_soils.py, bench wrong 25 → 24)


def _local_contrast(img: np.ndarray, sub: np.ndarray, origin: tuple[int, int], win: "SearchWindow", gains: np.ndarray,
                    thr: float, soil: float) -> tuple[float, float]:
    """(local contrast, core share) of a stage-1 candidate mask `sub` whose top-left grid cell is
    `origin`: at full resolution, (median −a* index of its pixels − median in a ring ~1–4 px
    round them: a 9 × 9 dilation minus a 3 × 3 one) / the ring's σ; and the share of `sub` left after a 3 × 3 erosion."""
    l0, t0 = origin
    h0, w0 = sub.shape
    sp = np.pad(sub.astype(np.uint8), 1)
    core = float(np.count_nonzero(cv2.erode(sp, np.ones((3, 3), np.uint8)))) / max(float(np.count_nonzero(sp)), 1.0)
    p = int(math.ceil((LC_RING[1] // 2 + 2) / min(win.sx, win.sy))) + 1  # grid cells of margin for the ring
    xa, xb = int(round(win.x0 + (l0 - p) * win.sx)), int(round(win.x0 + (l0 + w0 + p) * win.sx))
    ya, yb = int(round(win.y0 + (t0 - p) * win.sy)), int(round(win.y0 + (t0 + h0 + p) * win.sy))
    H, W = img.shape[:2]
    cx0, cy0, cx1, cy1 = max(xa, 0), max(ya, 0), min(xb, W), min(yb, H)
    if cx1 - cx0 < 4 or cy1 - cy0 < 4:
        return 0.0, core
    full = cv2.resize(np.pad(sub.astype(np.uint8), p), (xb - xa, yb - ya), interpolation=cv2.INTER_NEAREST)
    full = full[cy0 - ya:cy1 - ya, cx0 - xa:cx1 - xa]
    vf = vegetation_index(img[cy0:cy1, cx0:cx1], gains=gains, lab=True)
    m = ((vf > 0.5 * (thr + soil)) & (full > 0)).astype(np.uint8)
    if int(m.sum()) < 4:
        return 0.0, core
    a, b = LC_RING
    ring = cv2.dilate(m, np.ones((b, b), np.uint8)) > cv2.dilate(m, np.ones((a, a), np.uint8))
    if int(ring.sum()) < 8:
        return 0.0, core
    rv = vf[ring]
    return (median(vf[m > 0]) - median(rv)) / max(float(rv.std()), 1e-4), core
