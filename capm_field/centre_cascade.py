"""Stage 2 of the weed-centre detector: the centre of the chosen plant.

The plant is re-cut from the full-resolution frame at ~PLANT_PX across and the stage-2 estimators
are asked in a fixed order (`centre_fullres`): the first that answers wins. The estimators live in
`capm_field.plant_centre`, `capm_field.stalks`, `capm_field.compound_leaf` and
`capm_field.leaf_axes`; docs/perception.md §2 lists the order and why.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from . import axis_votes, compound_leaf, fan_apex, hub_petioles, leaf_axes, midribs, plant_centre, stalks, star_centre, straw_shape, tree_median
from .components import components
from .plant_window import plant_window
from .roi import Roi, roi_mask
from .vegetation import cap_clipped, pooled_index, vegetation_index
from .vegetation_mask import group_components, hysteresis

PLANT_PX = 80  # stage 2 (find its centre): plant bounding box resampled to about this size
MID_PX_STAGE2 = 120_000  # pixels of the intermediate image the plant crop's index is computed on
ONE_PEAK_HUB = 0.145  # a plant of ≥ 2 separate parts but one vote peak (small trefoils on long petioles read as
# thin) gets `compound_centre` if its strongest three-lobed hub reaches this (bench seeds 0–7, one-peak plants
# that compound_centre would answer: rosettes and grass ≤ 0.138, clovers ≥ 0.146; answers: 4 clovers 38.0 → 1.9,
# 25.5 → 1.6, 22.4 → 1.1, 18.8 → 13.9 mm, a rosette of 0.159 1.4 → 20.8 mm). Its compound flag is not used
# (rosettes with such hubs went to the geometric median: ~30 answers worse)
FINE_STALK_PX = 200  # (0: off) plant windows of ≥ this many image px whose stalks the ≤ stalks.MAX_PX
# grid did not show: searched again at ≤ this px, if the plant has compound leaves (clover trefoils: pale
# petioles 3–5 px wide fade into the soil's texture at a pitch ≥ 5 px). Field-photo seeds 0–5 and the shadow
# set: 21 answers better (0.33 → 0.02 S, 0.35 → 0.04 S), 2 worse (0.25 → 0.31, 0.03 → 0.06 S); bench seeds
# 0–7 one clover 6.7 → 3.3 mm, nothing else (its windows are smaller); +35–41 ms on the 3 of bench seed 0's
# 300 frames where it runs. From 100 px windows: bench seed 3 a clover 8.3 → 27.9 mm; for every plant, not
# only compound-leaved ones: a field-photo fat-hen's leaf veins and a stone's edge taken for stalks (0.02 →
# 0.57 S)
HUB_PETIOLES = True  # `hub_petioles.hub_petiole_centre` for compound leaves no estimator above answered
STAR_CHECK = True  # `star_centre.star_check` on every answer (session 59)
STALK_PEAKS = 2  # leaf-axis vote peaks (`axis_votes.vote_peaks`) from which stalks are looked for


def stalk_centre(img: np.ndarray, X0: int, Y0: int, kx: float, ky: float, plant: np.ndarray, gains: np.ndarray,
                 lab_index: bool, thr: float, soil: float,
                 max_px: int = stalks.MAX_PX, cap: bool = False) -> stalks.StalkPoints:
    """`stalks.stalk_points` (stalks' meeting point, lone stalk's centre end, whether that end is
    `stalks.CARRIED_END`'s) for a plant on the
    stage-2 grid (grid pixel (j, i) ↔ image (X0 + (j + 0.5)·kx − 0.5, Y0 + (i + 0.5)·ky − 0.5)).
    It works at the image's own pitch (stalks are 1–3 px wide there; coarser only for plant
    windows over `max_px`: stalks.MAX_PX, or FINE_STALK_PX in the second search), on a window
    reaching stalks.MARGIN × the plant's size round it (a clover's centre may lie outside the
    leaves that stage 1 grouped); answers in stage-2 grid pixels. `cap`: an over-exposed soil's
    clipped pixels are capped at the soil level (`vegetation.cap_clipped`)."""
    if not stalks.has_leaf_clusters(plant):  # (cheap, on the stage-2 grid: most plants stop here)
        return stalks.NONE
    win = plant_window(img, X0, Y0, kx, ky, plant.shape, max_px, stalks.MARGIN)
    if win is None:
        return stalks.NONE
    region = win.region
    grey = cv2.cvtColor(region, cv2.COLOR_BGR2GRAY).astype(np.float32) / 255.0
    vi = vegetation_index(region, gains=gains, lab=lab_index).astype(np.float32)
    if cap:
        cap_clipped(region, vi, soil)
    big = win.mask(plant)
    leaves = hysteresis(vi, thr, soil, np.ones(vi.shape, bool)) | big
    meet, lone, carried = stalks.stalk_points(grey, vi, leaves, big)
    return stalks.StalkPoints(None if meet is None else win.to_stage2(meet), None if lone is None else win.to_stage2(lone),
                              carried)


def separate_parts(plant: np.ndarray) -> int:
    """Number of the plant mask's connected parts of ≥ 2 % of its area."""
    n, _, stats, _ = components(plant)
    return int(np.count_nonzero(stats[1:, cv2.CC_STAT_AREA] >= 0.02 * stats[1:, cv2.CC_STAT_AREA].sum()))


MIDRIBS = True  # `midribs.midrib_centre` replaces a fallback's answer (tip axes, geometric or tree median) for a
# plant not of compound leaves (session 74). Bench seeds 0-11: 70 answers better, 22 worse by > 1 mm (rosettes; worst
# 2.0 -> 9.1 mm), wrong 50 -> 49 (a rosette 47.6 -> 1.9 mm); seeds 30-33 29 / 3, 34-37 33 / 4, wrong unchanged.
# Field-photo weeds seeds 3-4 (fresh; ± ROI, 640 frames): 53 better, 1 worse by > 0.02 S (plantain, thistle, fat-hen,
# dandelion); other renderer seeds 0-2 4 / 2; photo-like seeds 3-6 1 / 1. ~0.5-0.7 ms a frame
WIDE_FAN_ROUND = 0.10  # the fan test for round plants (THIN_ROUND ≤ r < this) before the medians (session 50).
# Bench seeds 0–7 wrong 36 → 34, seeds 8–11 28 → 27: grass 34.9 → 4.6, 30.6 → 6.5 mm, rosettes 66.8 → 5.3,
# 13.4 → 1.7, 17.4 → 2.0 mm; four seedlings worse (1.4–13.6 → 8.6–16.1 mm). With the fine votes (step 1's):
# the same fixed, five seedlings worse (up to 2.2 → 17.7 mm), the hand-made half-disc rosette 0.24 → 0.43 S.
# Held out: field photos and `stones_on_soils.py` the same, photo-like but one grass by 0.001 S; the other
# renderer without a ROI, two rosettes worse, seed 0's four-leaved one 0.21 → 0.50 S and seed 2 case 13 0.153 → 0.319 S
# (session 51; roundness 0.062, 0.071, among the fixed grass fans' 0.064, 0.077) (the "apex" a leaf's rounded end;
# tips, vote peaks, gaps, straightness and the plant's spread round the apex do not tell it from the grass)


def centre_fullres(img, box, thr: float, soil: float, gains: np.ndarray, roi: Roi | None, debug: dict | None = None,
                   lab_index: bool = False, stage1: tuple | None = None, cap: bool = False, straw_colour: bool = False):
    """Centre of the plant in `box` (full-image pixels). Returns (uv, n_tips, sharpness); `debug`
    gets the name of the estimator that gave it under "method". `straw_colour`: the plant's colour
    is not a green blade's (`candidates.green_blade`), so if it is one straight piece of even width
    (`straw_shape.lone_bar`), or two crossing (`straw_shape.crossed_bars`), it is straw: (None, 0, 0.0)
    as for no plant."""
    H, W = img.shape[:2]
    bx0, by0, bx1, by1 = box
    m = 0.12 * max(bx1 - bx0, by1 - by0) + 2
    X0, Y0 = max(int(math.floor(bx0 - m)), 0), max(int(math.floor(by0 - m)), 0)
    X1, Y1 = min(int(math.ceil(bx1 + m)), W), min(int(math.ceil(by1 + m)), H)
    crop = img[Y0:Y1, X0:X1]
    k = PLANT_PX / max(bx1 - bx0, by1 - by0)
    nw, nh = max(4, round(crop.shape[1] * k)), max(4, round(crop.shape[0] * k))
    kx, ky = crop.shape[1] / nw, crop.shape[0] / nh
    vi = pooled_index(crop, gains, (nw, nh), MID_PX_STAGE2, lab=lab_index, exact=True, cap=cap, cap_level=soil)
    inside = np.ones(vi.shape, bool)
    if roi is not None:
        inside = roi_mask(roi, vi.shape, X0, Y0, kx, ky)
    mask = hysteresis(vi, thr, soil, inside)
    n, lab, stats, _ = components(mask)
    if n <= 1:
        return None, 0, 0.0
    g = None
    if stage1 is not None:
        # the plant is what stage 1 chose (colour-checked, grouped): the components that overlap
        # its mask; straw or stones next to the plant must not become its stalks
        gm1, x1_0, y1_0, s1x, s1y = stage1
        gm1 = cv2.dilate(gm1.astype(np.uint8), np.ones((3, 3), np.uint8))
        jj = ((X0 + (np.arange(nw) + 0.5) * kx - 0.5) - x1_0 + 0.5) / s1x - 0.5
        ii = ((Y0 + (np.arange(nh) + 0.5) * ky - 0.5) - y1_0 + 0.5) / s1y - 0.5
        jj = np.clip(np.rint(jj).astype(int), 0, gm1.shape[1] - 1)
        ii = np.clip(np.rint(ii).astype(int), 0, gm1.shape[0] - 1)
        keep = gm1[np.ix_(ii, jj)] > 0
        g = [c for c in np.unique(lab[keep & (lab > 0)]) if stats[c, cv2.CC_STAT_AREA] >= 3] or None
    if g is None:
        # keep the components of this plant: the largest and those within reach of it
        big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        groups = group_components(lab, stats, [c for c in range(1, n) if stats[c, cv2.CC_STAT_AREA] >= 3])
        g = next((gr for gr in groups if big in gr), None)
        if g is None:  # even the largest component is under 3 px at this scale: nothing to locate
            return None, 0, 0.0
    plant = np.isin(lab, g)
    if int(plant.sum()) < 3 or plant.all():
        # (a mask without one soil pixel in a crop reaching past the plant's box: its threshold
        # has not told the plant from its soil, and its distance transform has no zero to measure from)
        return None, 0, 0.0
    ys_, xs_ = np.nonzero(plant)
    if straw_colour:  # one straight piece of even width, or two crossing, not green: straw
        bar = "lone_bar" if straw_shape.lone_bar(xs_, ys_) else "crossed_bars" if straw_shape.crossed_bars(xs_, ys_) else None
        if bar:
            if debug is not None:
                debug["method"] = bar
            return None, 0, 0.0
    dtp = cv2.distanceTransform(plant.astype(np.uint8), cv2.DIST_L2, 3)
    size = math.hypot(np.ptp(xs_) + 1, np.ptp(ys_) + 1)
    roundness = float(dtp[plant].mean()) / size  # mean half-width of the parts / plant size
    uv, method = None, None
    ntips, sharp = 3, 1.0  # confidence inputs when a stalk/part arrangement gives the centre
    # a fan (blades leaning one way from one base) first: its leaf axes converge at one end,
    # where no middle-of-the-parts estimate lands (not for broad leaves, whose outlines vote
    # across the plant: a half-disc of leaves had its "apex" on its rim, 0.43 L off)
    votes, n_peaks = None, 0  # leaf-axis votes: made when first needed (~1–2 ms)
    if roundness < axis_votes.THIN_ROUND:  # blades: their edges run along them, towards the base
        votes = axis_votes.axis_votes(vi, plant, size)
        n_peaks = axis_votes.vote_peaks(votes, size)
        uv = fan_apex.fan_apex(plant, votes, size, n_peaks, roundness)
        if uv is not None:
            method = "fan_apex"
    # plants with broad, rounded parts (clover trefoils, seedlings): trust where stalks or thin
    # parts meet, then (below) where trefoils point away from, or the middle of the parts
    # arranged round an empty centre; blades and narrow leaves (and round plants where none of
    # these applies): the tree median, computed only then
    parts = None  # (size, broad-parts mask): made when first needed, shared by the estimators below
    if uv is None and roundness >= plant_centre.HUB_MIN_ROUND:
        parts = plant_centre.broad_parts(plant)
        for name, fn in (("petiole_centre", lambda: plant_centre.petiole_centre(plant, vi, soil, thr, parts)),
                         ("line_hub", lambda: plant_centre.line_hub(plant, parts))):
            uv = fn()
            if uv is not None and not plant_centre.within_broad_hull(uv, parts):
                uv = None  # stalk-like lines outside the leaves (straw next to the plant)
            if uv is not None:
                method = name
                break
    if uv is None and votes is None:
        votes = axis_votes.axis_votes(vi, plant, size)
        n_peaks = axis_votes.vote_peaks(votes, size)
    compound = False
    hubs = None  # three-lobed hubs the estimators below used (the tip-axes guard reads these only)
    made: list = []  # the plant's `compound_hubs`, computed once, when first asked

    def plant_hubs() -> tuple:
        if not made:
            made.append(compound_leaf.compound_hubs(plant, vi, soil, size))
        return made[0]

    lone, carried = None, False  # the centre end of a lone stalk between two leaf clusters (after compound_centre)
    if uv is None and n_peaks >= STALK_PEAKS:
        uv, lone, carried = stalk_centre(img, X0, Y0, kx, ky, plant, gains, lab_index, thr, soil, cap=cap)
        if uv is None and (lone is None or carried) and FINE_STALK_PX and max(X1 - X0, Y1 - Y0) >= FINE_STALK_PX:
            # (a lone stalk's end told by the leaf it enters, `stalks.CARRIED_END`, waits for this search:
            # a field-photo clover's meeting stalks were found here, 0.045 S, its lone stalk's end 0.24 S off)
            hubs = plant_hubs()
            if compound_leaf.has_compound_leaves(hubs):  # (a lone stalk found only there is not used: not measured)
                uv, _, _ = stalk_centre(img, X0, Y0, kx, ky, plant, gains, lab_index, thr, soil, FINE_STALK_PX, cap=cap)
        if uv is not None:
            method = "stalk_centre"
    if uv is None and (n_peaks >= 2 or n_peaks == 1 and separate_parts(plant) >= 2):
        # compound leaves (clover trefoils: leaf axes converge at several hubs) whose stalks do
        # not show: the rays back from the hubs (after the stalk estimators, which are exact
        # when they answer: 0.3–2 mm cases became 5–12 mm when this came first)
        hubs = plant_hubs()
        if n_peaks < 2 and compound_leaf.strongest_hub(hubs) < ONE_PEAK_HUB:
            hubs = None
        else:
            uv = compound_leaf.compound_centre(plant, vi, soil, hubs)
            if uv is not None:
                method = "compound_centre"
            compound = n_peaks >= 2 and compound_leaf.has_compound_leaves(hubs)
    if uv is None and lone is not None and (compound or not carried):
        # one stalk carrying a leaf away from the rest of the plant: its end at the rest (after
        # compound_centre, exact when its rays agree; before the medians of the parts). An end told
        # by the leaf the stalk enters (`stalks.CARRIED_END`) only for compound leaves: a trefoil's
        # petiole enters at its hub, a simple leaf's at its rim (a field-photo mallow's end 0.15 → 0.25 S)
        uv, method = lone, "lone_stalk"
    if uv is None and roundness >= plant_centre.HUB_MIN_ROUND and stalks.has_leaf_clusters(plant):
        # compound leaves on petioles that meet in a V (one ridge, not two straight pieces, for
        # `petiole_centre` above): its arms apart, before the medians of the parts. Only for
        # compound leaves: for every plant of leaf clusters, field photos' seedlings, chickweed,
        # dandelions and fat-hens moved both ways (0.013 → 0.44 S), grass and rosettes too. (Not kept in
        # `hubs`: the tip-axes guard below reads only those the estimators above used)
        if compound_leaf.has_compound_leaves(plant_hubs()):
            parts = parts or plant_centre.broad_parts(plant)
            uv = plant_centre.petiole_centre(plant, vi, soil, thr, parts, split=True)
            if uv is not None and not plant_centre.within_broad_hull(uv, parts):
                uv = None
            if uv is not None:
                method = "petiole_split"
    if uv is None and HUB_PETIOLES and compound_leaf.has_compound_leaves(plant_hubs()):
        # trefoils whose rays back did not meet all round a centre (leaves to one side of it, or
        # only two or three of them): each ray confirmed by the petiole it runs along
        parts = parts or plant_centre.broad_parts(plant)
        uv = hub_petioles.hub_petiole_centre(img, X0, Y0, kx, ky, plant, parts[1], plant_hubs())
        if uv is not None:
            method = "hub_petioles"
    if uv is None and roundness >= plant_centre.HUB_MIN_ROUND:
        # separate parts round an empty centre (stalks too thin to see): the median of their
        # centroids — after `compound_centre`, which answers exactly for trefoils whose
        # middle leaflets point away from the centre (first, it took 13 of 24 stalkless
        # other-renderer clovers at 0.2–0.4 R off; after: those went to `compound_centre`)
        uv, method = plant_centre.component_median(plant), "component_median"
        if uv is None:
            # two parts (two leaves, stem unseen): where they are closest
            uv, method = plant_centre.pair_gap(plant), "pair_gap"
        if uv is not None:
            parts = parts or plant_centre.broad_parts(plant)
            uv = uv if plant_centre.within_broad_hull(uv, parts) else None
        if uv is None:
            method = None
    scattered = bool(axis_votes.SCATTER_PEAKS) and n_peaks >= axis_votes.SCATTER_PEAKS
    gmed = None  # the plant's geometric median: made when first needed
    if uv is None and not compound and (scattered or n_peaks >= leaf_axes.MIN_PEAKS and roundness >= leaf_axes.MIN_ROUND) \
            and compound_leaf.strongest_hub(hubs) < leaf_axes.HUB_GUARD:
        # leaf axes votes with several peaks (a rosette's broad leaves: their edges vote
        # everywhere, and the middle of the mask is pulled towards the biggest leaves): where the
        # leaves' axes traced back from their tips meet. Not when three-lobed hubs show (leaflet
        # axes meet at their trefoil's hub, not at the plant's centre), nor for 3 peaks of thin
        # blades (grass: the tree median and its votes find their base)
        gmed = plant_centre.geometric_median(np.c_[xs_, ys_].astype(float))
        met = leaf_axes.tip_axes_centre(plant, gmed)
        if met is not None:
            uv, method = met[0], "tip_axes"
    if uv is None and not compound and axis_votes.THIN_ROUND <= roundness < WIDE_FAN_ROUND:
        # a dense grass fan whose blades blur into one blob towards the base reads as round
        # (mean half-width ≥ THIN_ROUND), so step 1 skipped it and the medians below land
        # mid-fan; its blade axes still meet at the base: the fan test, with ≥ 3 far tips, its
        # apex from votes at the scale of the leaves' half-width (as the tree median's: at the
        # fine scale broad leaves' edges vote across the plant, and a half-disc of leaves or three
        # seedling leaves on one side peaked on the rim), its gates on the fine votes' peaks
        wide_votes = axis_votes.axis_votes(vi, plant, size, tree_median.vote_scale(roundness))
        uv = fan_apex.fan_apex(plant, wide_votes, size, n_peaks, roundness, min_tips=fan_apex.WIDE_FAN_TIPS)
        if uv is not None:
            method = "wide_fan"
    if uv is None:
        if compound or scattered:
            # leaf axes converge at many separate points (the hubs of compound leaves, e.g.
            # clover trefoils whose rays back did not meet, or the bases of scattered seedling
            # leaves, or the broad leaves of a rosette whose edges vote everywhere, where the
            # leaf axes did not meet either): no single apex in the votes (the tree median
            # slides along a trefoil's stalk: 15–46 mm off); the middle the parts are arranged
            # around
            method = "geometric_median"
            uv = gmed if gmed is not None else plant_centre.geometric_median(np.c_[xs_, ys_].astype(float))
    if uv is None:
        method = "tree_median"
        # leaf-axis votes for the tree median at the scale of the leaves' half-width: a smaller
        # window leaves the two edges of a broad leaf voting along two parallel lines that
        # miss its axis (and the centre) by the half-width
        scale = tree_median.vote_scale(roundness)
        fine = scale <= 0.015 or roundness >= axis_votes.THIN_ROUND  # votes unused for round parts (weight 0)
        uv, ntips, sharp = tree_median.tree_median(plant, vi, None, votes if fine else axis_votes.axis_votes(vi, plant, size, scale))
        if uv is None:
            return None, 0, 0.0
    if MIDRIBS and not compound and method in ("tip_axes", "geometric_median", "tree_median"):
        # a fallback's answer for broad leaves: where the lines inside the plant (midribs, veins,
        # petioles) converge, when they agree all round (`midribs`, session 74)
        full = cv2.resize(plant.astype(np.uint8), (crop.shape[1], crop.shape[0]), interpolation=cv2.INTER_NEAREST) > 0
        got = midribs.midrib_centre(cv2.cvtColor(crop, cv2.COLOR_BGR2GRAY), full)
        if got is not None:
            uv, method = np.array([(got[0][0] + 0.5) / kx - 0.5, (got[0][1] + 0.5) / ky - 0.5]), "midribs"
    if STAR_CHECK:
        # an answer from which most of a star-shaped plant is out of sight (a leaf's midrib taken
        # for a petiole, a median pulled onto one leaf): the point the plant radiates from
        star = star_centre.star_check(plant, uv)
        if star is not None:
            uv, method = star, f"{method}+star"
    if debug is not None:
        debug["method"] = method
        debug["roundness"] = roundness
    return np.array([X0 + (uv[0] + 0.5) * kx - 0.5, Y0 + (uv[1] + 0.5) * ky - 0.5]), ntips, sharp
