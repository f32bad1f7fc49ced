"""The review's Tuo & Wu toy problem (section 6.2)."""

import sys

import numpy as np
import pytest
from conftest import ROOT, assert_healthy, fit

sys.path.insert(0, str(ROOT / "case_studies" / "tuo_wu"))
import tuo_wu  # noqa: E402

PUBLISHED_THETA_STAR = -0.1789  # review, section 6.2


def test_l2_projection_by_quadrature_matches_the_review():
    # the review gives 4 decimals: agree to rounding
    assert tuo_wu.l2_projection() == pytest.approx(PUBLISHED_THETA_STAR, abs=5e-5)


def test_l2_loss_is_multimodal():
    grid = np.linspace(-2, 2, 401)
    loss = np.array([tuo_wu.l2_loss(t) for t in grid])
    local_minima = np.flatnonzero((loss[1:-1] < loss[:-2]) & (loss[1:-1] < loss[2:])) + 1
    assert len(local_minima) >= 2


@pytest.fixture(scope="module")
def koh_tuo_wu():
    # 4 x (500 + 500) left R-hat 1.012 and bulk ESS 239 on theta; 4 x (1000 + 1000): 1.003 and 692 (11 s)
    return fit(tuo_wu.problem(seed=1), simulator=tuo_wu.SIMULATOR, method="koh", chains=4,
               warmup=1000, draws=1000, seed=5)


def test_koh_on_tuo_wu(koh_tuo_wu):
    """Record what KOH gives. The review reports -0.0821 on its own data; KOH's
    target depends on the discrepancy prior (section 6.1), so this test checks
    that the reported summary is the posterior's, the modes weighted by their
    mass, not a blend of chains nor the highest-density mode."""
    result = koh_tuo_wu
    assert_healthy(result)
    summary = result.theta_summary()["theta"]
    print(f"KOH on Tuo & Wu (seed 1): median {summary['q50']:.4f}, "
          f"90 % [{summary['q05']:.4f}, {summary['q95']:.4f}], modes: "
          f"{[(m.chains, round(m.theta_mean['theta'], 4), m.weight) for m in result.modes]}")
    theta = np.asarray(result.idata["posterior"]["theta"])[..., 0]
    weights = [m.weight for m in result.modes] if len(result.modes) > 1 else [1.0]
    assert sum(weights) == pytest.approx(1)
    # the mixture's CDF at the reported quantiles, computed from each mode's draws
    for q in ("q05", "q50", "q95"):
        cdf = sum(w * np.mean(theta[m.chains] <= summary[q]) for w, m in zip(weights, result.modes, strict=False))
        assert cdf == pytest.approx(int(q[1:]) / 100, abs=0.01), q
    # the posterior predictive still tracks the true process (Tuo & Wu 2018)
    table = result.predict()
    truth = tuo_wu.zeta(table["x"].to_numpy())
    assert np.sqrt(np.mean((table["zeta_q50"] - truth) ** 2)) < 0.6
