"""Candidate plants of the weed detector: their colour and shape features, and the rules that
tell a live plant from soil, stones and straw.

A candidate is a connected part (or a group of parts) of the stage-1 vegetation mask of
`capm_field.detector`. `candidate_features` measures it; `plant_like` judges its colour in the
first look (G*) or the second (CIELAB −a*, `vivid`); `green_blade` exempts long green pieces
from the straw rules. Every threshold carries what it was measured on (docs/perception.md §2).
"""

from __future__ import annotations

import math

import numpy as np

from .order_stats import elongation, percentile, row_medians


def green_blade(f: dict) -> bool:
    """A long straight candidate that is no straw: green above red in the camera's own colours
    and after the white balance (a single grass blade, two cotyledons in a line: elongation 5–6
    at full resolution). Bench straw and other long non-weed pieces: min(g_raw, gr) ≤ 0.044.
    A teal blade or pair of cotyledons (blue near green: g_raw small) passes on gr ≥ TEAL_GR
    with G still above max(R, B) in the camera's colours: straw is yellow (bench seeds 0–3, long
    non-weed candidates at full resolution: gr ≤ 0.035)."""
    return min(f["g_raw"], f["gr"]) >= BLADE_GREEN or (f["gr"] >= TEAL_GR and f["g_raw"] >= BLADE_TEAL_RAW)


BLADE_GREEN = 0.048  # session 24 (was 0.06): bench straw ≤ 0.044; a two-leaf rosette of 0.05 (bench seed 4 case 40,
# elongation 5.9) and a field-photo seedling now found; nothing else moved on bench seeds 0–7, the other renderer,
# the photo-like and field-photo benches, stones_on_soils.py (31 of 384) or 200 fresh bare scenes (196 no plant)
BLADE_TEAL_RAW = 0.01  # g_raw of a teal blade: other renderer's bluish-green cotyledons 0.02–0.04
STRAW_ELONG_FULL = 5.0  # √(λ1/λ2) of the full-resolution mask; weeds measured ≤ 4.5 (but see `green_blade`)
STRAW_ELONG = 6.5  # same on the stage-1 grid (weeds measured ≤ 5.9 but one merged with straw)
STRAW_RAW = -0.012  # g_raw below which a long straight piece is straw (measured: straw −0.04 … −0.010, olive
# grass blades ≥ −0.005; bench seeds 0–3, plant-like pieces of elongation > STRAW_ELONG: the weed's own ≥ −0.0098,
# bare soil's down to −0.016; −0.02 → −0.012: bench bare soil 2 more of 180; bench weeds, other renderer seeds 0–2,
# photo-like grass (seed 3) and 200 fresh bare scenes unchanged)


def candidate_features(gm, vi, small, gains, soil, sig, cen, rad, origin: tuple[int, int] = (0, 0)) -> dict:
    """Features of one candidate plant (mask gm on the stage-1 grid, or on a crop of it whose
    top-left pixel is `origin` (x, y) of the grid, with vi and small cropped alike).

    g_p90: 90th percentile of the index (absolute), gsig: the same above the soil level in soil σ,
    gb: median (G − B)/(R + G + B + 30) after the soil white balance (leaves reflect far more
    green than blue; grey stones turned cyan-green by the white balance and straw do not),
    gr: the same with G − R (blue-green leaves, whose gb is low), sat: median saturation after
    white balance, g_raw: median (G − max(R, B))/(R + G + B + 30) before it, sat_raw: median
    saturation before it (a neutral stone is ≈ 0 there whatever the white balance makes of it),
    gm_raw: median (G − (R + B)/2)/(R + G + B + 30) before it (the green–magenta axis, across
    which daylight, shade and warm light barely move a colour: a grey stone stays ≈ 0 there),
    mass: Σ (index − soil), d: distance of the centroid from the ROI centre in ROI radii.
    """
    v = vi[gm]
    # colour planes of the candidate's pixels, raw and white-balanced (per-plane ufuncs: the same
    # values as reductions over the (n, 3) pixels, at a fraction of their per-call cost)
    b, g, r = small[gm].T.astype(np.float32)
    pb, pg, pr = b * gains[0], g * gains[1], r * gains[2]
    mx, mn = np.maximum(np.maximum(pb, pg), pr), np.minimum(np.minimum(pb, pg), pr)
    ys, xs = np.nonzero(gm)
    xs += origin[0]  # grid coordinates: the same values as from the uncropped mask
    ys += origin[1]
    g90 = percentile(v, 90)
    elong = elongation(xs, ys) if len(xs) >= 3 else 1.0
    ps, rs = pb + pg + pr + 30, b + g + r + 30
    rmax, rmin = np.maximum(np.maximum(b, g), r), np.minimum(np.minimum(b, g), r)
    # the six colour medians in one call (one partition per row instead of six calls)
    med = row_medians(np.stack([(pg - pb) / ps, (pg - pr) / ps, (mx - mn) / (mx + 1),
                                (g - np.maximum(b, r)) / rs, (rmax - rmin) / (rmax + 1),
                                (g - 0.5 * (b + r)) / rs]))
    return dict(
        elong=elong,
        area=float(len(v)),
        g_p90=g90,
        gsig=(g90 - soil) / sig,
        gb=float(med[0]),
        gr=float(med[1]),
        sat=float(med[2]),
        g_raw=float(med[3]),
        sat_raw=float(med[4]),
        gm_raw=float(med[5]),
        mass=float(np.sum(v - soil)),
        d=math.hypot(xs.mean() - cen[0], ys.mean() - cen[1]) / rad,
    )


STRONG_SIGMA = 12.0
VIVID_SAT, VIVID_GB = 0.42, 0.15  # second look: bare-soil candidates measured sat ≤ 0.38, gb ≤ 0.14
BIG_FRAC, BIG_GB, BIG_SAT, BIG_SIGMA = 0.01, 0.09, 0.30, 8.0  # second look: a candidate ≥ 1 % of the window
# (bench bare soil: those reach gb 0.081, saturation 0.24, 2.8 σ; weeds missed there: ≥ 0.096, 0.31)
HUGE_FRAC, HUGE_GB, HUGE_SAT = 0.02, 0.10, 0.33  # second look: a candidate ≥ 2 % of the window this coloured needs
# no margin in soil σ (a large pale rosette on a bright, grainy sand: 3.3 σ, gb 0.12, sat 0.36, bench seed 3
# case 80; every bench component that large off the weed measured gb ≤ 0.085, sat ≤ 0.29)
# second look, local contrast: a compact candidate in the colour band just below VIVID_* (where
# pale seedlings and soil tints overlap) is a plant when it stands out from the soil right round
# it (a leaf is a patch with an edge; a soil tint fades into its surroundings). Measured on bench
# seeds 0–3 (AUC 0.95 all seedlings vs all bare components; 0.70 for the missed ones): misses +
# wrong 53 → 51, bare soil unchanged (also 200 fresh bare scenes); photo-like seeds 3–6 +6
# detections, other renderer +2 (commit 6e662de)
LC_ELONG, LC_GB, LC_SAT, LC_SIGMA = 4.0, 0.085, 0.29, 5.0  # (LC_ELONG 3.5 until session 12: bench seed 2
# case 25, two cotyledons in a line at 3.7, was missed; 4.0 moved nothing else on the bench, 200 fresh bare
# scenes, other renderer seeds 0–2 or photo-like seeds 3–6)
LC_MIN = 5.8  # (index inside − ring median) / ring σ for a plant ...
LC_MIN_THICK, LC_CORE = 3.5, 0.44  # ... or this much with ≥ LC_CORE of it left by a 3 × 3 erosion (not a thin rim)
LC_RING = (3, 9)  # full-resolution dilations whose difference is the ring of soil round the candidate
# paler than LC_SAT: in the band only with twice LC_SIGMA over the soil (weaker colour, stronger margin). Bench
# seeds 0-3: +1 seedling, a grass 27 -> 7 mm (sat 0.278-0.290, >= 14 sigma); at 0.25 without the margin a soil patch
# of 200 fresh bare scenes (6.3 sigma) was a plant; photo-like, other renderer, stones unchanged
LC_SAT_PALE, LC_SIGMA_PALE = 0.25, 10.0


def contrast_band(f: dict) -> bool:
    """Whether the second look measures a candidate's local contrast (`_local_contrast`): only
    where the colour rule alone does not take it (below VIVID_SAT or VIVID_GB)."""
    sat_ok = f["sat"] >= LC_SAT or f["sat"] >= LC_SAT_PALE and f["gsig"] >= LC_SIGMA_PALE
    return f["elong"] <= LC_ELONG and f["gb"] >= LC_GB and sat_ok and f["gsig"] >= LC_SIGMA \
        and (f["sat"] < VIVID_SAT or f["gb"] < VIVID_GB)


def _stands_out(f: dict) -> bool:
    lc = f.get("lc", 0.0)
    return contrast_band(f) and (lc >= LC_MIN or lc >= LC_MIN_THICK and f.get("core", 0.0) >= LC_CORE)


def _large_and_coloured(f: dict) -> bool:
    """Second look: a large candidate needs less than the vivid colour (soil tints that large are
    dull): ≥ BIG_FRAC of the window with gb ≥ BIG_GB, saturation ≥ BIG_SAT and ≥ BIG_SIGMA soil σ,
    or ≥ HUGE_FRAC with gb ≥ HUGE_GB and saturation ≥ HUGE_SAT whatever its σ."""
    big = f["area_frac"] >= BIG_FRAC and f["gb"] >= BIG_GB and f["sat"] >= BIG_SAT and f["gsig"] >= BIG_SIGMA
    return big or f["area_frac"] >= HUGE_FRAC and f["gb"] >= HUGE_GB and f["sat"] >= HUGE_SAT


def _mealy(f: dict) -> bool:
    """Second look: a large plant (≥ MEALY_FRAC of the window) whose leaves a mealy or waxy
    bloom makes whitish (fat-hen, thistles: gb and saturation below any other rule's) but that is
    green above both red and blue in the camera's own colours (g_raw ≥ MEALY_RAW, gm_raw ≥ MEALY_GM)
    and far above the soil (≥ MEALY_SIGMA σ)."""
    return f["area_frac"] >= MEALY_FRAC and f["g_raw"] >= MEALY_RAW and f["gm_raw"] >= MEALY_GM and f["gsig"] >= MEALY_SIGMA


MEALY_FRAC, MEALY_RAW, MEALY_GM, MEALY_SIGMA = 0.03, 0.02, 0.045, 8.0  # (session 27. Field-photo seeds 0–5:
# with a ROI 8 fat-hens and thistles `no_plant` → within 0.14 S (they fill 15–23 % of the window); without one
# 2 wrong answers (a small plant chosen, 0.85–0.90 S) and 2 misses → ≤ 0.06 S (3–7 % of the photo). Bare-soil
# components of those colours: bench seeds 0–7 and 200 fresh bare scenes ≤ 0.53 % of the ROI, field-photo bare
# sets ≤ 1.1 % (moss); at 0.12 the photos without a ROI were not helped. Nothing else moved on the bench, stones,
# the other renderer or the photo-like bench)


def _cyan_green(f: dict) -> bool:
    """Second look: blue-green leaves that the soil white balance turned cyan (a reddish soil's
    gains lift blue, and cool light or a glaucous bloom already puts B ≈ G): blue at or just above
    green (gb ≥ CYAN_GB), but far greener than red (gr ≥ CYAN_GR) and strongly saturated
    (≥ CYAN_SAT) well above the soil (≥ CYAN_SIGMA σ). −a* segments such leaves whole; the teal
    rule wants G above B. Measured: the 1 005 second-look components of bench/stones_on_soils.py
    (grey stones, 12 soils, 4 casts) reach gr ≤ 0.09 and saturation ≤ 0.30; on bench seeds 0–3
    every second-look candidate with gr ≥ 0.1 and saturation ≥ 0.3 passed the other rules already."""
    return f["gb"] >= CYAN_GB and f["gr"] >= CYAN_GR and f["sat"] >= CYAN_SAT and f["gsig"] >= CYAN_SIGMA


CYAN_GB, CYAN_GR, CYAN_SAT, CYAN_SIGMA = -0.06, 0.15, 0.45, 8.0


def _large_teal(f: dict) -> bool:
    """Second look: a large plant (≥ MEALY_FRAC of the window) of blue-green leaves (teal thistles,
    glaucous rosettes): −a* segments it whole, but with B ≈ G its gb is near 0 and its green above
    red (gr) short of the teal and cyan rules, which small candidates need. Far greener than red
    (gr ≥ LTEAL_GR), saturated (≥ LTEAL_SAT), greener than magenta before the white balance
    (gm_raw ≥ MEALY_GM) and ≥ LTEAL_SIGMA soil σ out."""
    return f["area_frac"] >= MEALY_FRAC and f["gb"] >= CYAN_GB and f["gr"] >= LTEAL_GR and f["sat"] >= LTEAL_SAT \
        and f["gm_raw"] >= MEALY_GM and f["gsig"] >= LTEAL_SIGMA


LTEAL_GR, LTEAL_SAT, LTEAL_SIGMA = 0.085, 0.25, 8.0  # (session 29: field-photo teal thistles gr 0.09–0.14, sat
# 0.26–0.42; second-look stone components of bench/stones_on_soils.py gr ≤ 0.09, sat ≤ 0.30 and small: stones 31 of
# 384 as before; field-photo bare sets, 200 fresh bare scenes, bench seeds 0–7 unchanged)


def _raw_blue_green(f: dict) -> bool:
    """Second look: bluish-green leaves of middling colour (gb 0.04–0.08, saturation 0.22–0.30,
    below the vivid and teal rules) that are green above both red and blue in the camera's own
    colours (g_raw ≥ RAW_BG_RAW), greener than red after the white balance, ≥ RAW_BG_SIGMA soil σ
    out, and saturated before the white balance too (sat_raw ≥ RAW_BG_SAT_RAW: a grey stone under
    a green cast is as green in the raw image, but measured sat_raw ≤ 0.20)."""
    return f["g_raw"] >= RAW_BG_RAW and f["gr"] >= RAW_BG_GR and f["gsig"] >= RAW_BG_SIGMA \
        and f["sat"] >= RAW_BG_SAT and f["sat_raw"] >= RAW_BG_SAT_RAW


RAW_BG_RAW, RAW_BG_GR, RAW_BG_SIGMA, RAW_BG_SAT, RAW_BG_SAT_RAW = 0.02, 0.05, 8.0, 0.20, 0.23  # (session 13:
# other renderer's bluish-green grass and seedlings, g_raw 0.021–0.057, sat_raw 0.26; bench bare-soil components
# of the second look on seeds 0–3 and 200 fresh bare scenes: none passes; bench/stones_on_soils.py: 46 of 384
# without the sat_raw clause, 31 with it, as before the rule)


def plant_like(f: dict, vivid: bool = False) -> bool:
    """Whether a candidate's colour is that of a live plant rather than soil, stone or straw.

    Measured on the bench candidates (bench/perception_candidates.py, docs/perception.md):
    live leaves have gb ≥ 0.07 and saturation ≥ 0.2 after white balance, and either a clear
    absolute greenness (G* p90 ≥ 0.04) or a strong margin over the soil (≥ 5 σ) with gb ≥ 0.10.
    Grey-green (dull), glaucous and blue-green (teal) leaves have rules of their own, and so has
    a large candidate green above red and blue before and after the white balance (both looks). Any
    candidate must be greener than magenta before the white balance (gm_raw ≥ GM_RAW_MIN). The second look
    (`vivid`, −a*) takes vivid colours, teal leaves, large coloured candidates
    (`_large_and_coloured`), compact ones that stand out from the soil round them (`_stands_out`)
    and bluish-green ones that are green in the raw image too (`_raw_blue_green`).
    """
    if f["gm_raw"] < GM_RAW_MIN:
        # not greener than magenta in the camera's own colours: a grey stone (or anything
        # neutral) that the white balance on a purplish or red soil made look green
        return False
    if f["area_frac"] >= RAW_GREEN_FRAC and min(f["g_raw"], f["gr"], f["gb"]) >= RAW_GREEN and f["sat_raw"] >= RAW_BG_SAT_RAW:
        # large and green above both red and blue, in the camera's own colours and after the
        # white balance alike: a leaf, however wide the soil's spread (a two-tone soil puts σ so
        # high that a grass clearly above it stands only 4 σ out)
        return True
    if vivid and _mealy(f):
        return True
    margin = (f["gb"] - 0.07) / 0.07 + (f["sat"] - 0.2) / 0.2  # not at the edge of both at once
    if vivid and (f["sat"] < VIVID_SAT or f["gb"] < VIVID_GB) and not _large_and_coloured(f) and not _stands_out(f):
        if _raw_blue_green(f) or _cyan_green(f) or _large_teal(f):
            return True
        # blue-green leaves (G ≈ B: G* leaves them at the soil's level) far greener than red
        return f["gb"] >= TEAL_GB and f["sat"] >= TEAL_SAT and f["gsig"] >= 5 and f["gr"] >= TEAL_GR
    # the weaker the absolute greenness, the stronger the margin over the soil must be: ≥ 5 σ
    # with gb ≥ 0.10, or ≥ 12 σ with the base gb (dark olive grass on dark soil: G* p90 0.015
    # at 15 σ, gb 0.096 — demo seed 8)
    strong = f["gsig"] >= 5 and f["gb"] >= 0.10 or f["gsig"] >= STRONG_SIGMA
    if f["gb"] >= 0.07 and f["sat"] >= 0.2 and margin >= 0.1 and (f["g_p90"] >= 0.04 or strong):
        return True
    # grey- or blue-green leaves (glaucous, or dulled by overcast light): green above both red
    # and blue in the median, also before the white balance (which turns grey stones on a red
    # soil just as green), and far above the soil (≥ 12 σ)
    if not vivid and f["gsig"] >= STRONG_SIGMA and f["g_p90"] >= 0.035 and f["gb"] >= DULL_GB and f["gr"] >= DULL_GR \
            and f["sat"] >= DULL_SAT and f["g_raw"] >= DULL_RAW:
        return True
    # glaucous or dulled leaves of middling contrast (8–12 σ) whose green is clear after the
    # white balance (G* p90 ≥ 0.05) but only a little above blue: coloured in the raw image too
    # (a neutral stone that the white balance on a purplish soil turns just as green is not:
    # sat_raw ≤ 0.04 measured). Other renderer +1 %, photo-like seeds 0–6: +4 answers
    if not vivid and f["gsig"] >= GLAUC_SIGMA and f["g_p90"] >= GLAUC_G90 and f["gb"] >= GLAUC_GB \
            and f["gr"] >= GLAUC_GR and f["sat"] >= GLAUC_SAT and f["g_raw"] >= GLAUC_RAW and f["sat_raw"] >= GLAUC_SAT_RAW:
        return True
    # blue-green (glaucous) leaves: green barely above blue (gb < 0.07) but far above red,
    # further than any soil, stone or straw of the bench (gr ≤ 0.07 on its bare-soil frames)
    return not vivid and f["gb"] >= TEAL_GB and f["sat"] >= TEAL_SAT and f["gsig"] >= 5 \
        and (f["gr"] >= TEAL_GR or f["gr"] >= TEAL_GR_WEAK and f["g_p90"] >= 0.04)


DULL_GB, DULL_GR, DULL_SAT, DULL_RAW = 0.02, 0.03, 0.15, 0.02
RAW_GREEN, RAW_GREEN_FRAC = 0.04, 0.003  # (session 16: bench seeds 0–3 +1 found, −1 wrong, nothing else moved;
# no bare-soil component of either look on seeds 0–3 and 200 fresh bare scenes reaches 0.04 in all three; stones
# under bench/stones_on_soils.py's green cast do, with sat_raw 0.20–0.21, hence the raw blue-green rule's
# RAW_BG_SAT_RAW here too: 31 of 384 as before, 39 at sat_raw ≥ 0.20; other renderer, photo-like: unchanged)
GM_RAW_MIN = 0.009  # bench weeds measured ≥ 0.017 (1 % ≤ 0.032), a bluish grass of another renderer 0.010,
# neutral stones ≤ 0.007 (bench/stones_on_soils.py, 12 soils × 8 greys × 4 casts: plant answers
# 44 → 31 of 384; 20 of the rest under a green cast, which makes the stones green in the raw image too)
GLAUC_SIGMA, GLAUC_G90, GLAUC_GB, GLAUC_GR, GLAUC_SAT = 8.0, 0.04, 0.03, 0.015, 0.17  # (G90 0.05 until session 16:
# a pale mint-green photo-like clover at 0.049 and bench seed 2 case 5, a seedling at 0.042 (247 → 8 mm); no bench or
# fresh bare component and no stone of bench/stones_on_soils.py passes at 0.04; other renderer seed 0 wrong 4 → 3)
GLAUC_RAW, GLAUC_SAT_RAW = -0.01, 0.10  # the rescued leaves measured sat_raw 0.12–0.30
TEAL_GB, TEAL_SAT = 0.01, 0.22
TEAL_GR, TEAL_GR_WEAK = 0.12, 0.08  # gr = median (G − R)/(R + G + B + 30) after white balance
