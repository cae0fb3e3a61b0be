"""Centre of a compound-leaved plant (clover) from its trefoil hubs and the petioles leaving them.

Stage-2 estimator of the weed-centre detector (see `capm_field.centre_cascade`). A clover's
leaves sit at the ends of straight petioles from its centre, each with its middle leaflet
pointing straight away from it: round each hub (`compound_leaf.compound_hubs`) the three
leaflets' phase gives three candidate directions back to the centre. `compound_centre` asks the
hubs' rays to agree all round the centre, which fails when the leaves stand to one side of it
(the centre then lies outside the leaves' hull) or when there are only two or three hubs. Here
each ray is confirmed by the image instead: a petiole is a thin line, darker or lighter than the
soil along its whole length, so the second derivative of the grey image across the ray,
averaged along it, stands out of what the soil's texture gives on segments of that length. The
centre is where confirmed petioles of ≥ 2 hubs meet. Searched only along the hubs' candidate
rays (a few thousand samples), not over all lines in the window, so fainter petioles count than
`capm_field.stalks` can accept anywhere. Coordinates are (x, y).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .geometry import wrap_angle
from .order_stats import percentile
from .plant_window import plant_window

MAX_PX = 120  # the plant window at most this many px across on the working grid (petioles 1–3 px wide there)
MARGIN = 0.5  # × the plant window: how far round it the centre may lie
SIGMA = 1.0  # px of the working grid: the line filter's scale
FAN = 0.35  # rad each side of a hub's three candidate directions (middle leaflet ±0.2 rad, phase error)
FAN_STEP = 0.035  # rad between rays of a fan
RAY_MIN, RAY_MAX = 0.08, 0.95  # × plant size: petiole lengths searched
EDGE_K = 1.0  # evidence = |mean f_nn| − this × mean |f_n| (a leaf's or clod's edge is not a line)
MIN_FREE = 6  # samples outside the leaves a segment needs
N_REF = 300  # soil segments the evidence is compared with
REF_Q = 95  # ... at this percentile of theirs
Z_MIN = 1.5  # a petiole: evidence ≥ this × the soil segments' REF_Q percentile
MIN_HUBS = 2  # confirmed petioles that must meet ...
MEET_ANGLE = 0.5  # rad: ... two of them at least this far apart in direction


def _second_derivatives(grey: np.ndarray) -> np.ndarray:
    """(fxx, fxy, fyy, fx, fy) of the grey image smoothed at SIGMA, stacked (h, w, 5) float32."""
    f = cv2.GaussianBlur(grey, (0, 0), SIGMA)
    fxx = cv2.Sobel(f, cv2.CV_32F, 2, 0, ksize=3) / 4
    fyy = cv2.Sobel(f, cv2.CV_32F, 0, 2, ksize=3) / 4
    fxy = cv2.Sobel(f, cv2.CV_32F, 1, 1, ksize=3) / 4
    fx = cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3) / 8
    fy = cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3) / 8
    return np.dstack([fxx, fxy, fyy, fx, fy])


def _sample(D: np.ndarray, free: np.ndarray, x: np.ndarray, y: np.ndarray, th: np.ndarray):
    """Along rays of direction th (broadcast with x, y): f_nn and |f_n| across them, and whether
    each sample is on the grid and outside the leaves (`free`)."""
    h, w = free.shape
    mx, my = x.astype(np.float32), y.astype(np.float32)
    ch = [cv2.remap(D[:, :, k], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT) for k in range(5)]
    ok = cv2.remap(free, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0) > 0
    ok &= (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    nx, ny = -np.sin(th), np.cos(th)
    fnn = ch[0] * nx * nx + 2 * ch[1] * nx * ny + ch[2] * ny * ny
    fn = np.abs(ch[3] * nx + ch[4] * ny)
    return np.where(ok, fnn, 0.0), np.where(ok, fn, 0.0), ok


def _evidence(s_fnn: np.ndarray, s_fn: np.ndarray, ok: np.ndarray, axis: int = -1) -> tuple[np.ndarray, np.ndarray]:
    """Cumulative segment evidence along `axis`: (|mean f_nn| − EDGE_K · mean |f_n|, samples) over
    the free samples from the ray's start to each point."""
    n = np.cumsum(ok, axis=axis)
    a = np.cumsum(s_fnn, axis=axis)
    b = np.cumsum(s_fn, axis=axis)
    nn = np.maximum(n, 1)
    return np.abs(a) / nn - EDGE_K * b / nn, n


def hub_petiole_centre(img: np.ndarray, X0: int, Y0: int, kx: float, ky: float, plant: np.ndarray,
                       broad: np.ndarray, hubs: tuple) -> np.ndarray | None:
    """Where the confirmed petioles of ≥ MIN_HUBS trefoil hubs meet, in stage-2 grid pixels
    (grid pixel (j, i) ↔ image (X0 + (j + 0.5)·kx − 0.5, Y0 + (i + 0.5)·ky − 0.5)), or None.
    `plant`: the stage-2 mask, `broad`: its broad parts (`plant_centre.broad_parts`), `hubs`:
    `compound_leaf.compound_hubs` of the plant."""
    P, _, th0 = hubs
    ys_, xs_ = np.nonzero(plant)
    if len(P) < MIN_HUBS or len(xs_) < 30:
        return None
    win = plant_window(img, X0, Y0, kx, ky, plant.shape, MAX_PX, MARGIN)
    if win is None:
        return None
    NH, NW = win.region.shape[:2]
    D = _second_derivatives(cv2.cvtColor(win.region, cv2.COLOR_BGR2GRAY).astype(np.float32) / 255.0)
    whole = win.mask(plant)
    free = (~win.mask(broad)).astype(np.uint8)
    size = math.hypot((np.ptp(xs_) + 1) * kx / win.p_x, (np.ptp(ys_) + 1) * ky / win.p_y)  # plant size, working px
    Pw = win.from_stage2(np.asarray(P, float))
    # the soil's evidence on segments of a petiole's typical length, anywhere off the plant
    soil_pts = np.argwhere(~cv2.dilate(whole.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool))
    if len(soil_pts) < 50:
        return None
    rng = np.random.default_rng(0)  # fixed: the same frame gives the same answer
    L = max(int(0.4 * size), 6)
    pick = soil_pts[rng.integers(0, len(soil_pts), N_REF)]
    a = rng.uniform(0, np.pi, N_REF)
    t = np.arange(L, dtype=np.float32)
    rx = pick[:, 1, None] + t[None] * np.cos(a)[:, None]
    ry = pick[:, 0, None] + t[None] * np.sin(a)[:, None]
    s1, _, ok = _sample(D, np.ones_like(free), rx, ry, np.broadcast_to(a[:, None], rx.shape))
    n_ref = ok.sum(axis=1)
    valid = n_ref >= L // 2
    if int(valid.sum()) < 30:
        return None
    # the scale: how strongly soil segments look like a line (|mean f_nn|, before the edge penalty)
    line_ref = np.abs(s1.sum(axis=1)) / np.maximum(n_ref, 1)
    ref = max(float(percentile(line_ref[valid], REF_Q)), 1e-6)
    # each hub's fans of rays round its three candidate directions back to the centre
    fan = np.arange(-FAN, FAN + 1e-9, FAN_STEP)
    mids = th0[:, None] + np.pi + np.arange(3)[None, :] * (2 * np.pi / 3)  # (n, 3)
    dirs = (mids[:, :, None] + fan[None, None, :]).reshape(len(P), -1)  # (n, 3f)
    T = max(int(RAY_MAX * size), 4)
    tt = np.arange(1, T + 1, dtype=np.float32)
    rx = Pw[:, 0, None, None] + tt[None, None] * np.cos(dirs)[:, :, None]
    ry = Pw[:, 1, None, None] + tt[None, None] * np.sin(dirs)[:, :, None]
    n_h, n_r = dirs.shape
    s1, s2, ok = _sample(D, free, rx.reshape(n_h * n_r, T), ry.reshape(n_h * n_r, T),
                         np.broadcast_to(dirs[:, :, None], rx.shape).reshape(n_h * n_r, T))
    E, N = _evidence(s1, s2, ok)
    Z = np.where(N >= MIN_FREE, E / ref, 0.0).reshape(n_h, n_r, T)
    Z[:, :, : max(int(RAY_MIN * size), 1)] = 0.0
    # score every point of a coarse grid: each hub backs it with the evidence of the ray through it
    gy, gx = np.mgrid[0:NH:2, 0:NW:2].astype(np.float32)
    score = np.zeros(gx.shape, np.float32)
    count = np.zeros(gx.shape, np.int32)
    backs = []  # per hub: where it backs a point, and the direction it comes from
    nf = len(fan)
    for i in range(n_h):
        dx, dy = gx - Pw[i, 0], gy - Pw[i, 1]
        r = np.hypot(dx, dy)
        ang = np.arctan2(dy, dx)
        ti = np.clip(np.rint(r).astype(np.int32) - 1, 0, T - 1)
        z = np.zeros(gx.shape)
        for j in range(3):  # the nearest ray of the fan round each candidate direction (within a step of its rim)
            rel = wrap_angle(ang - mids[i, j])
            k = j * nf + np.clip(np.rint((rel + FAN) / FAN_STEP).astype(np.int32), 0, nf - 1)
            z = np.where((np.abs(rel) <= FAN + FAN_STEP) & (r >= 1) & (r <= T), Z[i][k, ti], z)
        good = z >= Z_MIN
        score += np.where(good, z, 0.0).astype(np.float32)
        count += good
        backs.append((good, ang))
    # petioles of different leaves come from different sides: two nearly parallel rays meet at
    # an ill-defined point (along one leaf's edge, or two hubs of one trefoil)
    wide = np.zeros(gx.shape, bool)
    for i in range(n_h):
        for j in range(i + 1, n_h):
            wide |= backs[i][0] & backs[j][0] & (np.abs(wrap_angle(backs[i][1] - backs[j][1])) >= MEET_ANGLE)
    score = np.where((count >= MIN_HUBS) & wide, score, 0.0)
    if float(score.max()) <= 0:
        return None
    iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)
    return win.to_stage2(np.array([gx[iy, ix], gy[iy, ix]], float))
