
import numpy as np
import pytest

from capm_field.geometry import SE2
from capm_field.probability import p_closed_form, p_monte_carlo, p_numeric
from capm_field.reachability import RadialSet


@pytest.mark.parametrize("rho", [0.0, 0.3, 0.6, 0.9, 1.4])
@pytest.mark.parametrize("sigma", [0.2, 0.5])
def test_closed_form_matches_monte_carlo(rho, sigma):
    rm = RadialSet(((0.35, 0.87),))
    rng = np.random.default_rng(int(rho * 100 + sigma * 10))
    n = 400_000
    mpoi = rng.normal(scale=sigma, size=(n, 2))
    d = np.hypot(mpoi[:, 0] - rho, mpoi[:, 1])
    mc = float(np.mean(rm.contains(d)))
    assert float(p_closed_form(rho, sigma, rm)) == pytest.approx(mc, abs=0.004)


def test_closed_form_two_intervals_adds_up():
    a, b = RadialSet(((0.2, 0.5),)), RadialSet(((0.7, 1.0),))
    both = RadialSet(((0.2, 0.5), (0.7, 1.0)))
    for rho in (0.0, 0.5, 1.2):
        assert float(p_closed_form(rho, 0.4, both)) == pytest.approx(float(p_closed_form(rho, 0.4, a) + p_closed_form(rho, 0.4, b)))


def test_numeric_integration_agrees_with_closed_form_and_mc(regions, core):
    """Numeric p over the full map (which leaves out the 60° sector behind the arm: one IK branch
    per radius, joint 1's ±150°; other branches reach part of it, docs/model.md) matches
    Monte Carlo on the same map; the annular closed form ignores that sector, so it bounds the
    numeric value from above and equals it where the sector holds no probability mass."""
    rng = np.random.default_rng(5)
    for rho, sigma in ((0.4, 0.5), (0.7, 0.5), (1.0, 0.2), (1.0, 0.5)):
        body = SE2(-rho, 0.0, 0.0)  # facing the TROI at the origin
        cf = float(p_closed_form(rho, sigma, regions.R_m_radial(None)))
        num = p_numeric(regions, body, np.zeros(2), sigma**2 * np.eye(2))
        mc = p_monte_carlo(regions, body, np.zeros(2), sigma**2 * np.eye(2), 200_000, rng)
        assert num == pytest.approx(mc, abs=0.006)
        assert num <= cf + 0.01
        if sigma <= 0.2:  # nothing behind the arm: closed form and map agree
            assert num == pytest.approx(cf, abs=0.01)
    # Anisotropic Σ_w: only the numeric route applies; check it against Monte Carlo.
    body = SE2(-0.7, 0.0, 0.0)
    cov = np.array([[0.3, 0.1], [0.1, 0.1]])
    num = p_numeric(regions, body, np.array([0.05, 0.0]), cov)
    mc = p_monte_carlo(regions, body, np.array([0.05, 0.0]), cov, 200_000, rng)
    assert num == pytest.approx(mc, abs=0.006)
