"""Order statistics and shape moments of small pixel sets, without numpy's per-call overhead.

The detector takes percentiles, medians and elongations of a few hundred pixels per candidate
several times a frame; `np.percentile` / `np.median` / `np.cov` cost ~10× the work itself there.
`percentile`, `median` and `row_medians` return numpy's values bit for bit (same partition, same
float operations; property-tested against numpy), so answers do not move when they replace it.
"""

from __future__ import annotations

import math

import numpy as np


def percentile(v: np.ndarray, q: float | tuple) -> float | tuple:
    """`np.percentile(v, q)` of a 1-D array by one partition, with numpy's own float operations
    (so the same values): q a number (interpolated in v's precision, as numpy does for a
    scalar q) or a tuple of them (interpolated in float64, returned as a tuple). np.percentile's
    overhead is ~10× a partition of the few hundred pixels of a candidate."""
    n = v.size
    spots = []
    for qi in (q if isinstance(q, tuple) else (q,)):
        k = (n - 1) * (qi / 100)  # numpy's virtual index for the linear method
        lo = n - 1 if k >= n - 1 else max(int(math.floor(k)), 0)
        spots.append((lo, min(lo + 1, n - 1), k - math.floor(k)))
    p = np.partition(v, sorted({i for lo, hi, _ in spots for i in (lo, hi)}))
    out = []
    for lo, hi, g in spots:
        a, b = p[lo], p[hi]
        d = b - a
        if isinstance(q, tuple):
            a, b, d = float(a), float(b), float(d)
        out.append(float(b - d * (1 - g)) if g >= 0.5 else float(a + d * g))
    return tuple(out) if isinstance(q, tuple) else out[0]


def median(v: np.ndarray) -> float:
    """`np.median(v)` of a 1-D array (same value) by one partition."""
    return float(row_medians(v[None])[0])


def row_medians(a: np.ndarray) -> np.ndarray:
    """`np.median(a, axis=1)` (same values) by one partition, without np.median's overhead
    (NaN for rows of no element, as numpy, without its warning)."""
    n = a.shape[1]
    if n == 0:
        return np.full(a.shape[0], np.nan)
    k = n // 2
    if n % 2:
        return np.partition(a, k, axis=1)[:, k]
    p = np.partition(a, (k - 1, k), axis=1)
    return (p[:, k - 1] + p[:, k]) / 2


def elongation(xs: np.ndarray, ys: np.ndarray) -> float:
    """√(λ1/λ2) of the covariance of pixel coordinates (≥ 2 pixels) plus ¼ px² (a pixel's own
    extent), from the 2 × 2 eigenvalues in closed form (np.cov + eigvalsh cost ~0.1 ms a call)."""
    n = len(xs)
    x = xs - xs.mean()
    y = ys - ys.mean()
    sxx, syy, sxy = float(x @ x) / (n - 1) + 0.25, float(y @ y) / (n - 1) + 0.25, float(x @ y) / (n - 1)
    m, r = 0.5 * (sxx + syy), math.hypot(0.5 * (sxx - syy), sxy)
    return math.sqrt((m + r) / max(m - r, 1e-12))
