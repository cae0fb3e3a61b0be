"""Weed-centre detector: the MPOI X̄_w (biological centre) of a plant in an arm-camera close-up.

Classical pipeline, no learned weights, sizes relative to the plant or the search window:
  1. the search window (`capm_field.search_window`): the projected TROI ellipse R^TROI_I grown by
     ROI_MARGIN, downscaled; a frame that is not usable (dtype, shape, exposure, flatness,
     pixel noise) → reason "bad_image", never raise;
  2. stage 1, find the plant (`capm_field.plant_choice`): vegetation index G* = (G − max(R, B)) /
     (R + G + B + 30) after a white balance that maps the soil to a typical soil colour,
     max-pooled so thin blades and stalks survive; threshold at soil + 5 σ with hysteresis;
     components whose own colour is not a plant's (stones, straw; anything not greener than
     magenta in the camera's own colours) dropped; the rest grouped into plants and scored by
     green area and centrality; none → "no_plant", a close runner-up → "ambiguous". Here
     (`_looks`): either answer, or a small (seedling-sized) or pale first choice, gets a second
     look on CIELAB −a* (yellow-green leaves) that accepts vivid plants only; a window that a
     large cast shadow splits gets both looks again in its lit and its shadowed part, each with
     its own soil statistics (`capm_field.shadow_regions`): their plant is the answer where the
     whole window found none, and replaces the whole window's answer if it is another plant
     scoring higher;
  3. stage 2, find its centre (`_locate` → `capm_field.centre_cascade`): the chosen plant, joined
     with near-equal or same-coloured parts close to it, re-cut from the full-resolution frame
     at ~PLANT_PX across; centre from `capm_field.plant_centre` (stalk crossings, the geometric
     median of plants whose leaf axes converge at many points), `capm_field.tree_median` (the
     tree median of geodesic distances to the leaf tips with leaf-axis votes),
     `capm_field.compound_leaf` (clover trefoils) or `capm_field.leaf_axes` (rosettes: where the
     leaves' axes meet);
  4. "cut_by_border" when the plant touches the frame edge near the centre; confidence.
The pixel returned follows the camera module's convention (pixel centres at integer coordinates);
`ground_centre` (`capm_field.detection`) maps it to the field with H⁻¹. Measured figures and the
reasons behind each threshold: docs/perception.md. The index images are made in
`capm_field.vegetation`, thresholded and grouped in `capm_field.vegetation_mask`; candidates are
measured and judged in `capm_field.candidates`; the ROI is `capm_field.roi`.
"""

from __future__ import annotations

import functools
import logging
import math
import threading
from dataclasses import replace

import cv2
import numpy as np
from threadpoolctl import ThreadpoolController

from .candidates import green_blade
from .centre_cascade import centre_fullres
from .components import components
from .detection import Detection, Reason, ground_centre
from .plant_choice import AMBIGUOUS, Choice, choose, mask_box
from .roi import Roi, RoiLike, roi_from_troi
from .search_window import SearchWindow, search_window
from .shadow_regions import shadow_regions
from .vegetation import soil_gains

__all__ = ["Detection", "Reason", "Roi", "RoiLike", "detect_centre", "ground_centre", "roi_from_troi"]

log = logging.getLogger(__name__)


# ---- entry point --------------------------------------------------------------------------------
def detect_centre(image_bgr: np.ndarray, roi: RoiLike = None, debug: dict | None = None) -> Detection:
    """Find the biological centre of the main plant in a BGR uint8 image (never raises).

    roi: None (whole image), a `Roi`, a 3×3 image conic (pᵀCp ≤ 0 inside), an OpenCV-style
    ellipse ((cu, cv), (width, height), angle_deg), a circle ((cu, cv), r) or (cu, cv, r), or an
    H×W mask of the region (non-zero inside; its equal-moment ellipse is used, `Roi.from_mask`).
    A malformed roi gives "bad_image".
    """
    try:
        with _one_blas_thread:
            win = search_window(image_bgr, roi)
            if isinstance(win, Detection):
                return win
            if debug is not None:
                debug["noise"] = win.noise  # the index image's colour noise (`search_window.DENOISE_FROM`)
            det, chosen = _looks(image_bgr, win, debug)
            if det.reason == "no_plant":
                det = _in_shadow_parts(image_bgr, win, debug) or det
            elif det.reason is None:
                # the whole window's statistics may also have hidden the weed in one part while
                # another plant (a small sunlit one) was chosen: a part's plant that is not the
                # chosen one and outscores it replaces it
                det = _in_shadow_parts(image_bgr, win, debug, beat=SHADOW_GAIN * chosen["best"],
                                       other=chosen["box"]) or det
            return det
    except Exception:  # the contract is "never raise": a bug must not stop a mission ...
        # ... but it must not go unseen either: the traceback goes to the log (and so the run's)
        log.exception("weed-centre detector failed on a %s %s image; answering bad_image",
                      getattr(image_bgr, "shape", "?"), getattr(image_bgr, "dtype", type(image_bgr).__name__))
        return Detection(None, 0.0, "bad_image")


class _OneBlasThread:
    """The BLAS libraries (numpy's, scipy's, any other loaded) held to one thread while any
    detection runs, and given back their own setting when the last one ends.

    The detector's matrix products are small (moments of a plant's pixels, the tree median's
    tips × nodes), yet OpenBLAS splits a product of a few thousand elements between its threads,
    and with the other core busy (the mission's drivers and log, another process) each split
    waits for it: 9 ms instead of 0.06 ms for the moments of a 5 000–15 000-pixel plant (session
    37, other work running beside the bench). The detector's budget is one core. The setting is
    process-wide, so detections in several threads share one limit (counted): the first sets it,
    the last restores it (~10 µs each)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._users = 0
        self._limiter = None  # threadpoolctl's limiter of the first detection in

    def __enter__(self) -> None:
        blas = _blas_libraries()
        with self._lock:
            if self._users == 0 and blas is not None:
                self._limiter = blas.limit(limits=1)
            self._users += 1

    def __exit__(self, *exc) -> None:
        with self._lock:
            self._users -= 1
            if self._users == 0 and self._limiter is not None:
                limiter, self._limiter = self._limiter, None
                limiter.restore_original_limits()


_one_blas_thread = _OneBlasThread()


@functools.cache
def _blas_libraries():
    """threadpoolctl's handle on the BLAS libraries loaded in the process (found once, ~6 ms), or
    None if they cannot be inspected (then the detector runs with their default threads)."""
    try:
        return ThreadpoolController().select(user_api="blas")
    except Exception:  # noqa: BLE001 (an unusual platform must not stop a detection)
        log.warning("BLAS thread pools cannot be inspected: the detector may use more than one core",
                    exc_info=True)
        return None


def _looks(image_bgr: np.ndarray, win: SearchWindow, debug: dict | None) -> tuple[Detection, dict]:
    """Both looks at one window (G*, then CIELAB −a* where G* found no plant, an ambiguous one or a
    small or pale one): the Detection, and the stage-1 "best" score and "feat"ures of the plant it
    answers (an empty dict if none; see `_detect`)."""
    first: dict = {}
    det = _detect(image_bgr, None, debug, first=first, win=win)
    if det.reason in ("no_plant", "ambiguous"):
        # second look on the green–red axis of CIELAB: yellow-green leaves (young seedlings,
        # chlorotic plants, warm light) reflect nearly as much red as green, so G − max(R, B)
        # leaves them at the soil's level; only vivid candidates count (soil tints come up too)
        # (also after an "ambiguous" first look: a pale plant split in two by G* is one in −a*)
        second: dict = {}
        det2 = _detect(image_bgr, None, debug, vivid=True, first=second, win=win)
        if (det.reason == "ambiguous" and det2.reason is None and second["best"] <= SMALL_GAIN * first["best"]
                and not _boxes_meet([second["box"]], first["contenders"])):
            # the second look chose something else than the plants in question, and nothing
            # clearly larger (a vivid speck) (a clover's centre lies between its leaflets'
            # boxes: the chosen plant's box must meet one, not hold the centre)
            return det, first
        if det2.reason is None or (det.reason == "no_plant" and det2.reason != "no_plant"):
            return det2, second
    elif det.reason is None and (first["best"] < SMALL_PLANT * win.n_in or first["feat"]["g_p90"] < PALE_G90
                                 or first["feat"]["gsig"] < FAINT_SIGMA):
        # a small first choice (seedling-sized) may be a vivid speck while the weed is a pale
        # seedling only the second look segments; a first choice of low absolute greenness may
        # be only the greenest part of a yellow-green plant, which −a* segments whole: take
        # the second look's choice when it scores clearly higher (bench seeds 0–3: wrong
        # 39 → 36, > 15 mm 110 → 106 for the small ones)
        # (the second look's plant is chosen first; its centre is sought only if it is taken.
        # Its debug entries join `debug` only then)
        dbg2: dict | None = {} if debug is not None else None
        second = {}
        choice = choose(image_bgr, win, vivid=True, debug=dbg2, first=second)
        if isinstance(choice, Choice) and (choice.best > SMALL_GAIN * first["best"] or (
                # or another plant, scoring higher, where the second look turned the first one away
                # (not plant-coloured in −a*: a tinted soil patch the first look took, the weed too pale for G*)
                choice.best > REJECTED_GAIN * first["best"] and not _boxes_meet([second["box"]], [first["box"]])
                and _boxes_meet([first["box"]], second.get("rejected", []))) or (
                # or the same plant, segmented far more completely (yellow-green parts, petioles)
                second["feat"]["area"] >= WHOLE_GAIN * first["feat"]["area"]
                and _boxes_meet([second["box"]], [first["box"]]))):
            det2 = _locate(image_bgr, win, choice, dbg2)
            if det2.reason is None:
                if debug is not None and dbg2 is not None:
                    _merge_debug(debug, dbg2)
                return det2, second
    return det, first


def _in_shadow_parts(image_bgr: np.ndarray, win: SearchWindow, debug: dict | None, beat: float = 0.0,
                     other: tuple | None = None) -> Detection | None:
    """Both looks again in the lit and in the shadowed part of a window that a large cast shadow
    splits (`capm_field.shadow_regions`), each with its own white balance and soil threshold;
    the best-scoring plant of ≥ SHADOW_MIN_PLANT of its part, green in the camera's own colours
    unless ≥ SHADOW_BIG of it, or None. After the whole window's answer (full-image box `other`),
    only a plant whose box does not meet it and that scores above `beat` counts."""
    best: tuple[float, Detection, dict | None] | None = None
    for part, core in shadow_regions(win.small, win.inside):
        if win.clipped is not None:  # over-exposed soil: its statistics from the unclipped pixels
            core = core & ~win.clipped
        n = int(np.count_nonzero(part))
        if n < 16 or np.count_nonzero(core) < 16:
            continue
        sub = replace(win, inside=part, n_in=n, gains=soil_gains(win.small, core), soil=core)
        dbg: dict | None = {} if debug is not None else None  # joins `debug` only if taken
        det, chosen = _looks(image_bgr, sub, dbg)
        if det.reason is not None or (other is not None and _boxes_meet([chosen["box"]], [other])):
            continue
        f = chosen["feat"]
        if (f["area"] >= SHADOW_MIN_PLANT * n and (f["g_raw"] > SHADOW_RAW_G or f["area"] >= SHADOW_BIG * n)
                and chosen["best"] > (beat if best is None else best[0])):
            best = (chosen["best"], det, dbg)
    if best is None:
        return None
    if debug is not None and best[2] is not None:
        _merge_debug(debug, best[2])
        debug["shadow_part"] = True
    return best[1]


SHADOW_GAIN = 1.0  # × the whole window's choice's score that a part's other plant must exceed to replace it
# (session 26, field-photo seeds 0–5 and the photographer's-shadow sets: 2 wrong answers right, fat-hens in
# the shadow outscoring a small sunlit plant by 1.46× and 3.9×; bench seeds 0–7: no answer replaced)
SHADOW_MIN_PLANT = 0.002  # least stage-1 area of a plant found in one part of a shadowed window, × the
# part's pixels: the soil under sky light alone is tinted green where it is yellowish, and specks of it
# and sharpening halos at the shadow's edge (≤ 0.1 % on bare frames) stand out of that part's statistics
SHADOW_RAW_G = 0.0  # its median G − max(R, B) (raw, `g_raw`) must exceed this ... (the lower σ of a part made
SHADOW_BIG = 0.01  # ... unless it is this × its part: olive straws crossing in a bench shadow, g_raw −0.03 and
# 0.3 % of the part, a plant; found weeds have g_raw ≥ 0.004, but for a fat-hen lit by blue sky only, 6 %)


SMALL_PLANT = 0.003  # first choice's score / ROI pixels (stage-1 grid) below which the second look also runs
# (~25 % of the bench's weed frames, mostly seedlings; 0.01 measured 1 fewer wrong on seeds 0–3 but
# +5 ms median latency, 0.003 +1.7 ms; session 9, second look choosing before locating: 0.01 gave
# 3 fewer wrong and p90 −0.3 to −1.1 mm on seeds 0–3, +3 ms median (paired) — the −a* index alone
# costs ~4 ms a frame; not taken while the median is at the 20 ms target)
SMALL_GAIN = 1.5  # the second look's choice must score this × the first's to replace it ...
REJECTED_GAIN = 1.0  # ... or this × if it is another plant and the second look turned the first's away (session
# 69, bench seeds 0–11: wrong 51 → 50, a seedling 209.2 → 5.7 mm, seed 10 case 45, the case it was made for, nothing
# else moved; seeds 30–33 nothing moved; the sealed seeds 34–37: wrong 24 → 23, 1 answer better, none worse)
WHOLE_GAIN = 1.3  # ... or be the same plant (boxes meet) with this × its stage-1 area (bench seeds 0–3:
# wrong 20 → 18, 11 answers ≥ 2 mm better, 3 worse at 1.5; 1.3 with PALE_G90 0.07, session 58, below)
FAINT_SIGMA = 6.0  # first choice's G* p90 over the soil, in soil σ, below which the second look also runs: a
# blue-green plant on a reddish soil, whose white balance lifts blue, clears G*'s 5 σ in one leaf only
PALE_G90 = 0.07  # first choice's G* p90 below which the second look also runs (at 0.05: +8 % of the bench's
# frames; bench and photo-like benches: 6 answers ≥ 0.1 S better, 1 worse; always: +10 ms median). Session 58,
# 0.05 → 0.07 and WHOLE_GAIN 1.5 → 1.3 (bench seeds 0–11: wrong 61 → 57, three grass fans whose thin blades G*
# segmented in part 31–39 → 6–9 mm and a clover 38.6 → 19.7 mm, none broken; 101 answers moved by > 1 mm, 52
# better, 49 worse; detected and bare soil unchanged; the second look runs on ~9 % more frames)


def _merge_debug(debug: dict, extra: dict) -> None:
    """`extra`'s lists (components, candidates) appended to `debug`'s; its other entries replace them."""
    for k, v in extra.items():
        if isinstance(v, list):
            debug.setdefault(k, []).extend(v)
        else:
            debug[k] = v


def _boxes_meet(a: list, b: list) -> bool:
    """Whether a box (x0, y0, x1, y1) of `a` overlaps one of `b` (None: no box)."""
    return any(ax0 <= bx1 and bx0 <= ax1 and ay0 <= by1 and by0 <= ay1
               for ax0, ay0, ax1, ay1 in filter(None, a) for bx0, by0, bx1, by1 in filter(None, b))


def _detect(img: np.ndarray, roi_in: RoiLike, debug: dict | None = None, vivid: bool = False,
            first: dict | None = None, win: SearchWindow | None = None) -> Detection:
    """One look (G* or, with `vivid`, CIELAB −a*): the plant is chosen (`choose`), then its
    centre is found (`_locate`). `first` receives the full-image boxes of the candidates within
    0.8 of the best score under "contenders" (those an "ambiguous" is about), the best score
    under "best", the chosen candidate's features under "feat" and the boxes of the components
    the second look's colour rules turned away under "rejected" (if any). `win`: the frame's
    `search_window(img, roi_in)` when already made."""
    if win is None:
        win = search_window(img, roi_in)
        if isinstance(win, Detection):
            return win
    choice = choose(img, win, vivid, debug, first)
    return choice if isinstance(choice, Detection) else _locate(img, win, choice, debug)


def _grid_box(mask: np.ndarray) -> tuple[int, int, int, int]:
    """(x, y, w, h) of a stage-1 grid mask's pixels: OpenCV's bounding box of the 0/1 image (the
    extremes of np.nonzero, in ~1/20 of its time on the stage-1 grid)."""
    return cv2.boundingRect(np.ascontiguousarray(mask).view(np.uint8))


def _box_parts(mask: np.ndarray) -> np.ndarray:
    """The parts of a plant's stage-1 mask that set stage 2's box: without the specks that stage 1's
    grouping chained to a large plant (each joined speck widens the group, and with it the gap the
    next may cross). Stage 2 resamples the box to ~PLANT_PX across, so specks far out coarsen the
    plant itself: a clover of 13 300 full-image px grouped with nine specks (each ≤ 2 % of the group)
    had a box 3.2× its own, its 2 px petioles vanished and its centre landed on a leaflet, 57.6 mm
    off (bench seed 7 case 27; 0.8 mm with this). A speck here: a part < SPECK_SHARE of the mask's
    area lying > SPECK_GAP × the larger parts' diameter from them; the box is made without specks
    only when they inflate its diagonal ≥ SPECK_INFLATION× (smaller changes of the grid only move
    answers either way). The specks stay in the mask (stage 2 keeps what falls in its crop)."""
    # on the mask's bounding box: the same labels, boxes and chamfer distances, 0.75 → 0.18 ms a call
    # (cProfile, bench seed 0's 300 frames, ~1 call a frame) against labelling the whole grid
    bx, by, bw, bh = _grid_box(mask)
    if bw == 0:
        return mask
    n, lab, stats, _ = components(mask[by:by + bh, bx:bx + bw])
    if n <= 2:
        return mask
    area = stats[1:, cv2.CC_STAT_AREA]
    small = area < SPECK_SHARE * area.sum()
    if small.all():  # (over 50 parts, none of them large: no plant to leave specks out of)
        return mask
    core = np.isin(lab, 1 + np.flatnonzero(~small))
    whole = math.hypot(bw, bh)
    diam = math.hypot(*_grid_box(core)[2:])
    if whole < SPECK_INFLATION * diam:  # (the near specks added below only widen the core's box)
        return mask
    dist = cv2.distanceTransform((~core).astype(np.uint8), cv2.DIST_L2, 3)
    for c in 1 + np.flatnonzero(small):
        x, y, w, h = stats[c, :4]
        if float(dist[y:y + h, x:x + w][lab[y:y + h, x:x + w] == c].min()) <= SPECK_GAP * diam:
            core |= lab == c
    if whole < SPECK_INFLATION * math.hypot(*_grid_box(core)[2:]):
        return mask
    out = np.zeros_like(mask)
    out[by:by + bh, bx:bx + bw] = core
    return out


def _merge_gap(f: dict, f0: dict | None) -> float:
    """How far (× the union's diameter) candidate `f` may lie from the best candidate `f0`'s
    union to join it: MERGE_GAP, or MERGE_GAP_SAME if it has f0's colour (a clover's trefoils on
    long petioles are one plant's leaves, as far apart as the plant is wide); f0 None: MERGE_GAP."""
    same = f0 is not None and abs(f["gb"] - f0["gb"]) <= SAME_GB and abs(f["sat"] - f0["sat"]) <= SAME_SAT
    return MERGE_GAP_SAME if same else MERGE_GAP


def _locate(img: np.ndarray, win: SearchWindow, choice: Choice, debug: dict | None = None) -> Detection:
    """Stage 2 of one look: the centre of the best-scored plant of `choice` (joined with near-equal
    candidates close to it), whether it is cut by the border or ambiguous, and a confidence."""
    H, W = img.shape[:2]
    roi, x0, y0, x1, y1, sx, sy = win.roi, win.x0, win.y0, win.x1, win.y1, win.sx, win.sy
    vivid, gains, thr, soil_level, contrast, lab, scored = (choice.vivid, choice.gains, choice.thr, choice.soil_level,
                                                            choice.contrast, choice.lab, choice.scored)
    best_score, gmask = scored[0][0], scored[0][1]
    to_full = win.to_full
    if best_score <= 0:
        return Detection(None, 0.0, "no_plant")
    runner = scored[1][0] / best_score if len(scored) > 1 else 0.0
    if runner > AMBIGUOUS or (roi is not None and runner >= PART_MERGE):
        # near-equal candidates close together are parts of one plant (clover trefoils whose
        # stalks are too thin to segment): grow the best by every scored candidate within
        # MERGE_GAP × the union's diameter, and score what is left against the union. Within a
        # TROI, smaller parts (≥ PART_MERGE of the best) join too: a clover's trefoils are of
        # uneven size, and the centre is between them, not on the largest; those of the best's
        # colour may lie farther (`_merge_gap`; not among near-equal contenders: three equal grey
        # stones that the colour rules took were "ambiguous", and would have been one plant)
        low = 0.0 if runner > AMBIGUOUS else PART_MERGE * best_score
        best_f0 = scored[0][4] if runner <= AMBIGUOUS else None
        rest = [t for t in scored[1:] if t[0] > low]
        while True:
            diam = math.hypot(*_grid_box(gmask)[2:])
            dist = cv2.distanceTransform((~gmask).astype(np.uint8), cv2.DIST_L2, 3)
            near = [t for t in rest if float(dist[t[1]].min()) < _merge_gap(t[4], best_f0) * diam]
            if not near:
                break
            for t in near:
                gmask = gmask | t[1]
                best_score += t[0]
            rest = [t for t in rest if not any(t is u for u in near)]
        runner = max((t[0] for t in rest), default=0.0) / best_score
    if debug is not None:  # the stage-1 mask: 1 every component, 2 the plant located (after merging)
        full = np.zeros((H, W), np.uint8)
        lbl = np.where(gmask, 2, (lab > 0).astype(np.uint8)).astype(np.uint8)
        full[y0:y1, x0:x1] = cv2.resize(lbl, (x1 - x0, y1 - y0), interpolation=cv2.INTER_NEAREST)
        debug["mask_full"] = full

    # ---- stage 2: centre on a plant-normalised grid from the full-resolution crop
    gx, gy, gw, gh = _grid_box(_box_parts(gmask))
    bx0, by0, bx1, by1 = mask_box(np.array([gx, gx + gw - 1]), np.array([gy, gy + gh - 1]), to_full)
    centre, tips, sharp = centre_fullres(img, (bx0, by0, bx1, by1), thr, soil_level, gains, roi, debug, lab_index=vivid,
                                          stage1=(gmask, x0, y0, sx, sy), cap=win.overexposed,
                                          straw_colour=not green_blade(scored[0][4]))
    if centre is None:
        return Detection(None, 0.0, "no_plant")

    # ---- border, ambiguity, confidence
    size = max(bx1 - bx0, by1 - by0)
    border_d = min(centre[0] + 0.5, centre[1] + 0.5, W - 0.5 - centre[0], H - 0.5 - centre[1])
    touches = bx0 <= 1 or by0 <= 1 or bx1 >= W - 2 or by1 >= H - 2
    if touches and border_d < 0.15 * size:
        return Detection(None, 0.1, "cut_by_border")
    conf = min(1.0, contrast / 0.1) * (0.6 + 0.4 * min(1.0, tips / 3)) * (1 - 0.7 * runner) * (0.7 + 0.3 * sharp)
    if touches:
        conf *= 0.8
    if roi is not None and not roi.contains(centre[None], 1.0)[0]:
        conf *= 0.6
    pix = (float(centre[0]), float(centre[1]))
    if runner > AMBIGUOUS:
        return Detection(pix, float(np.clip(conf, 0, 0.3)), "ambiguous")
    return Detection(pix, float(np.clip(conf, 0.0, 1.0)))


SPECK_SHARE, SPECK_GAP, SPECK_INFLATION = 0.02, 0.2, 1.25  # `_box_parts` (session 48; bench seeds 0–7: wrong
# 37 → 36, 33 answers moved, 22 by > 1 mm: 15 better, 7 worse; fresh seeds 8–11: wrong 29 → 28, 7 better, 5 worse
# (a rosette 7.9 → 101.6 mm: a leaf's midrib read as a petiole on the finer grid). Without the inflation gate
# (every box without its specks): 47 moved by > 1 mm on seeds 0–7, wrong 37, a rosette 18.5 → 47.3 mm)
MERGE_GAP = 0.5  # ... unless the contenders lie within this × the union's diameter: one plant
# (seed 1 case 207: a clover in two halves 0.38 diameters apart; 0.7 joined a third plant)
PART_MERGE = 0.3  # with a ROI, candidates scoring ≥ this × the best also join it within MERGE_GAP (bench
# seeds 0–7: 5 clovers better (46 → 1.1, 31.8 → 0.3, 25.7 → 6.2 mm), 2 worse (0.8 → 12.1, 1.3 → 2.2 mm);
# 0.15 the same; 0.5 only one better. Without a ROI it gave photo-like seed 4 a wrong answer: not there)
MERGE_GAP_SAME = 1.0  # ... and within this × the diameter if of the best's colour (|Δgb| ≤ SAME_GB, |Δsat| ≤
SAME_GB, SAME_SAT = 0.02, 0.05  # SAME_SAT): trefoils on long petioles (bench seeds 0–7: a clover 38.5 → 0.6 mm,
# one 23.1 → 25.5 mm; 1.5 joined 3 seedlings to distractors). Among near-equal contenders too it fixed a clover
# (46.2 → 3.4 mm), but stones_on_soils.py answered 35 of 384 frames, not 31: three equal stones as one plant

