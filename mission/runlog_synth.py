"""A synthetic mission's worth of run-log traffic: for the logging benchmark and the log tests.

Not a simulation: poses and images are made up, only the message mix and rates are realistic
(transforms at 20 Hz, igniter state at 5 Hz, two 1280×720 images, a plan, key states, a
detection, regions and energy per target, a few events).
"""

from __future__ import annotations

import math
import time
from collections import defaultdict
from typing import Callable

import numpy as np

from capm_field.geometry import SE2
from capm_field.keystates import TROI, KeyState, Plan
from capm_field.roi import Roi

from .runlog import RunLog

TF_HZ = 20
IGNITER_HZ = 5


def synthetic_image(width: int, height: int, seed: int) -> np.ndarray:
    """Soil-like BGR image: smooth gradient + low-amplitude noise + a green blob (compresses like a photo)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width]
    base = 90 + 30 * np.sin(xx / 97.0 + seed) * np.cos(yy / 71.0)
    img = np.empty((height, width, 3), np.uint8)
    noise = rng.normal(0, 12, (height, width))
    img[..., 0] = np.clip(base * 0.6 + noise, 0, 255)
    img[..., 1] = np.clip(base * 0.8 + noise, 0, 255)
    img[..., 2] = np.clip(base + noise, 0, 255)
    cx, cy = width // 2 + rng.integers(-100, 100), height // 2 + rng.integers(-80, 80)
    blob = (xx - cx) ** 2 + (yy - cy) ** 2 < 60**2
    img[blob] = (40, 170, 60)
    return img


class Timed:
    """Wraps a RunLog and adds up the wall time of each method (the benchmark's figure)."""

    def __init__(self, log: RunLog) -> None:
        self._log = log
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)

    def __getattr__(self, name: str) -> Callable:
        fn = getattr(self._log, name)

        def wrapped(*a, **k):
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                self.seconds[name] += time.perf_counter() - t0
                self.calls[name] += 1

        return wrapped


def synthetic_mission(
    log: RunLog | Timed,
    *,
    n_targets: int = 15,
    seconds_per_target: float = 4.0,
    images_per_target: int = 2,
    t0_ns: int = 1_000_000_000,
    width: int = 1280,
    height: int = 720,
    on_tick: Callable[[int], None] | None = None,
) -> int:
    """Log a mission; returns the last t_ns. `on_tick(t_ns)` runs after each transforms call."""
    dt = 1_000_000_000 // TF_HZ
    t = t0_ns
    pose = SE2(0.0, 0.0, 0.0)
    total_energy = 0.0
    moves = 0
    q = np.array([0.0, 0.8, -1.2, 0.3, 0.0, 0.0])
    images = [synthetic_image(width, height, s) for s in range(min(4, images_per_target * n_targets))]
    n_img = 0
    log.event(t, "info", "mission start", targets=n_targets)
    for i in range(n_targets):
        tid = f"t{i:02d}"
        troi = TROI(1.5 * (i + 1), 0.4 * (-1) ** i, 0.05, tid)
        k1 = SE2(troi.x - 0.55, troi.y * 0.5, 0.0)
        end = SE2(troi.x + 0.2, 0.0, 0.0)
        ks = (
            KeyState("x_k0", pose),
            KeyState("x_b,k1", k1),
            KeyState("x_e,k2", k1, arm="observe", target=troi.xy, radius=troi.r),
            KeyState("x_e,k3", k1, arm="flame", target=troi.xy),
            KeyState("x_kmax", end),
        )
        plan = Plan("capm", troi, pose, end, ks, p_upper=0.8, expected_cost=12.5 + i, fallback_k3=SE2(troi.x - 0.4, troi.y, 0.0),
                    terms={"objective": 12.5 + i, "r_eff": 0.5, "sigma": 0.03})
        log.plan(t, tid, plan)
        log.regions(t, tid, troi, [(0.35, 0.62)], [(0.30, 0.55)], None)
        log.key_state(t, tid, "capm", ks[0])
        n_ticks = int(seconds_per_target * TF_HZ)
        start = pose
        flame_from, flame_to = int(0.7 * n_ticks), int(0.85 * n_ticks)
        image_ticks = {int(n_ticks * (0.45 + 0.05 * j)) for j in range(images_per_target)}
        for k in range(n_ticks):
            a = min(1.0, k / (0.4 * n_ticks))
            pose = SE2(start.x + a * (k1.x - start.x), start.y + a * (k1.y - start.y), 0.0)
            qk = q + 0.2 * math.sin(k / 10.0)
            log.transforms(t, pose, qk)
            if k == int(0.4 * n_ticks):
                moves += 1
                log.key_state(t, tid, "capm", ks[1])
                log.key_state(t, tid, "capm", ks[2])
            if k in image_ticks:
                log.image(t, images[n_img % len(images)], tid)
                n_img += 1
                if k == min(image_ticks):
                    mpoi = (troi.x + 0.01, troi.y - 0.02)
                    rim = Roi.from_ellipse((width / 2, height / 2), (0.3 * width, 0.35 * height), 10.0).rim()  # made up
                    log.detection(t, tid, (650.0, 340.0), 0.91, None, mpoi, rim)
                    log.regions(t, tid, troi, [(0.35, 0.62)], [(0.30, 0.55)], mpoi)
                    log.truth_mpoi(t, tid, (troi.x + 0.012, troi.y - 0.018))
                    log.event(t, "info", "MPOI detected", target=tid, confidence=0.91)
            if k == flame_from:
                log.key_state(t, tid, "capm", ks[3])
                log.event(t, "info", "flame on", target=tid)
            if k == flame_to:
                log.event(t, "info", "flame off", target=tid)
            if k % (TF_HZ // IGNITER_HZ) == 0:
                on = flame_from <= k < flame_to
                log.igniter(t, on, True, 1.0 - 0.01 * i, None, on or k < flame_from, [] if on else ["not_aiming"], True, on, False)
            if on_tick is not None:
                on_tick(t)
            t += dt
        total_energy += 10.0 + i
        log.key_state(t, tid, "capm", ks[4], note="done")
        log.energy(t, total_energy, tid, 10.0 + i, moves)
        log.event(t, "info", "target done", target=tid, energy=10.0 + i)
    log.event(t, "info", "mission end")
    return t
