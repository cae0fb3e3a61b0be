"""p(x_b,k1): probability that the observation pose is also a manipulation pose (paper eq. 9–10).

p(x_b,k1) = ∫ p(X̂_w) · 1[x_b,k1 ∈ R_m(X̂_w)] dX̂_w with the MPOI prior X̂_w ~ N(X_w, Σ_w).

* Closed form for an isotropic prior (Σ_w = σ²I) and an annular R_m = ∪[r_in, r_out] around the
  arm base: with ρ = ‖arm_base(x_b,k1) − X_w‖, ‖arm_base − X̂_w‖²/σ² is non-central χ² with 2 dof
  and non-centrality ρ²/σ², so p = Σ F(r_out²/σ²; 2, ρ²/σ²) − F(r_in²/σ²; 2, ρ²/σ²).
* Numeric integration over the reachability map otherwise (any Σ_w, bearing limits of R_m).
"""

from __future__ import annotations

import numpy as np
from scipy.special import chndtr  # the non-central χ² CDF as a bare ufunc (= scipy.stats.ncx2.cdf)
from scipy.stats import multivariate_normal

from .geometry import SE2
from .reachability import RadialSet, Regions


def p_closed_form(rho: np.ndarray | float, sigma: float, rm: RadialSet) -> np.ndarray:
    """Closed-form p for distances ρ (arm base to X_w), isotropic σ and radial set R_m."""
    rho = np.asarray(rho, dtype=float)
    nc = (rho / sigma) ** 2
    p = np.zeros_like(rho)
    for a, b in rm.intervals:
        p = p + chndtr((b / sigma) ** 2, 2, nc) - chndtr((a / sigma) ** 2, 2, nc)
    return np.clip(p, 0.0, 1.0)


def p_numeric(regions: Regions, body: SE2, mean_xy: np.ndarray, cov: np.ndarray, n: int = 161, span: float = 4.5) -> float:
    """p by integrating the Gaussian over an n×n grid (±span std) against the full R_m map."""
    mean_xy = np.asarray(mean_xy, dtype=float)
    cov = np.asarray(cov, dtype=float)
    w, V = np.linalg.eigh(cov)
    s = np.sqrt(np.maximum(w, 1e-18))
    u = np.linspace(-span, span, n)
    du = u[1] - u[0]
    U1, U2 = np.meshgrid(u, u, indexing="ij")
    # Grid in the whitened frame: X = mean + V·diag(s)·u, weights = standard normal pdf · du².
    pts = mean_xy + (np.stack([U1.ravel() * s[0], U2.ravel() * s[1]], 1) @ V.T)
    wts = np.exp(-0.5 * (U1.ravel() ** 2 + U2.ravel() ** 2)) / (2 * np.pi) * du * du
    inside = regions.in_R_m(body, pts)
    return float(np.sum(wts[inside]))


def p_monte_carlo(regions: Regions, body: SE2, mean_xy: np.ndarray, cov: np.ndarray, n: int, rng: np.random.Generator) -> float:
    """Monte Carlo estimate of p (reference for tests)."""
    pts = multivariate_normal(mean=np.asarray(mean_xy, float), cov=np.asarray(cov, float)).rvs(size=n, random_state=rng)
    return float(np.mean(regions.in_R_m(body, np.atleast_2d(pts))))
