"""A scale between fidelities linear in the inputs, rho(x) = beta_0 + x' beta_x
(Le Gratiet & Garnier 2014, section 2; Kennedy & O'Hagan 2000): the
co-kriging against the recursive formulas written out here, stage 1's
estimate of beta against a known linear rho, the "cheap runs do not help"
flag, and the refusals."""

import numpy as np
import pandas as pd
import pytest
from conftest import assert_healthy, fit
from scipy import linalg

import stancal
from stancal.fitting.stage_one import fidelity_levels
from stancal.numerics import multifidelity as mf
from stancal.numerics.scalable_emulator import Hyperparameters, run_covariance, run_factor, se_correlation
from stancal.problem.config import ConfigError, load_config
from stancal.problem.validation import DataError


def linear_rho(intercept: float, slopes: np.ndarray, points: np.ndarray) -> np.ndarray:
    """rho at points whose first len(slopes) columns are the inputs."""
    return intercept + points[:, : len(slopes)] @ slopes


def recursive_predict(levels: list[mf.Level], points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Le Gratiet & Garnier (2014), eq. (9)-(10) with rho_k(x), for nested designs:
    mu_k(x) = rho_k(x) mu_{k-1}(x) + m_k + k_k' K_k^-1 (y_k - rho_k(D_k) y_{k-1}(D_k) - m_k),
    s2_k(x) = rho_k(x)^2 s2_{k-1}(x) + s2_{g_k}(x)."""
    mean, variance = np.zeros(len(points)), np.zeros(len(points))
    for k, lv in enumerate(levels):
        h = lv.hyperparameters
        if k == 0:
            below, rho_runs, rho_points = np.zeros(len(lv.y)), np.zeros(len(lv.y)), np.zeros(len(points))
        else:
            matched = [int(np.flatnonzero((levels[k - 1].xt == row).all(1))[0]) for row in lv.xt]  # nested
            below = levels[k - 1].y[matched]
            rho_runs, rho_points = (linear_rho(lv.rho, lv.rho_slope, lv.xt), linear_rho(lv.rho, lv.rho_slope, points))
        factor = run_factor(lv.xt, h)
        cross = h.sd**2 * se_correlation(points, lv.xt, h.length_scale)
        own_mean = h.mean + cross @ linalg.cho_solve(factor, lv.y - rho_runs * below - h.mean)
        own_variance = h.sd**2 - np.einsum("ij,ji->i", cross, linalg.cho_solve(factor, cross.T))
        mean, variance = rho_points * mean + own_mean, rho_points**2 * variance + own_variance
    return mean, np.maximum(variance, 0.0)


@pytest.mark.parametrize("sizes", [(14, 6), (22, 10, 5)])
def test_cokriging_with_rho_of_x_equals_the_recursive_formulas(sizes):
    rng = np.random.default_rng(4)
    xts = [rng.uniform(size=(sizes[0], 3))]  # two inputs, one theta
    for n in sizes[1:]:
        xts.append(xts[-1][rng.choice(len(xts[-1]), n, replace=False)])  # nested
    ys = [np.sin(3 * xt[:, 0]) + xt[:, 1] * xt[:, 2] * (k + 1) for k, xt in enumerate(xts)]
    slopes = [np.zeros(2), np.array([0.9, -0.6]), np.array([-0.5, 0.4])]
    levels = [mf.Level(Hyperparameters(0.2 * k, 1.0 / (k + 1), np.full(3, 0.35 + 0.1 * k), 0.0),
                       [1.0, 0.8, 1.3][k], xt, y, slopes[k])
              for k, (xt, y) in enumerate(zip(xts, ys, strict=True))]
    points = rng.uniform(size=(30, 3))
    mean, variance = mf.predict(levels, points)
    ref_mean, ref_variance = recursive_predict(levels, points)
    # the two differ only by the jitter on the diagonals (1e-6 of each variance)
    np.testing.assert_allclose(mean, ref_mean, atol=1e-4)
    np.testing.assert_allclose(variance, ref_variance, atol=1e-4)
    assert variance.max() > 1e-2  # away from the runs
    constant = [mf.Level(lv.hyperparameters, lv.rho, lv.xt, lv.y) for lv in levels]
    assert np.abs(mf.predict(constant, points)[0] - mean).max() > 0.05  # the slopes matter here


def cheap(x: np.ndarray, theta: np.ndarray) -> np.ndarray:
    return np.sin(4 * x) + theta * np.cos(3 * x)


def expensive(x: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """(0.5 + 1.2 x) times the cheap simulator plus a smooth shortfall: rho(x) = 0.5 + 1.2 x."""
    return (0.5 + 1.2 * x) * cheap(x, theta) + 0.3 * (x - theta) ** 2


def two_level_runs(n_low: int, n_high: int, seed: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    rng = np.random.default_rng(seed)
    xt_low, xt_high = rng.uniform(size=(n_low, 2)), rng.uniform(size=(n_high, 2))  # not nested
    return ([xt_low, xt_high],
            [cheap(xt_low[:, 0], xt_low[:, 1]), expensive(xt_high[:, 0], xt_high[:, 1])])


def test_stage_one_recovers_a_known_linear_rho_by_gls():
    xts, ys = two_level_runs(80, 25, seed=8)
    levels = mf.fit_levels(xts, ys, seed=0, slopes=1)
    top = levels[1]
    # exact 0.5 and 1.2; found 0.490 and 1.217 (the fit is deterministic; seeds 5 to 8 of the runs
    # give intercepts 0.490 to 0.507 and slopes 1.200 to 1.217)
    assert top.rho == pytest.approx(0.5, abs=0.04)
    assert top.rho_slope[0] == pytest.approx(1.2, abs=0.06)
    # at the mode the coefficients are their GLS estimate given g_2's hyperparameters
    np.testing.assert_allclose(mf.gls_rho(levels, 1), top.rho_coefficients, atol=2e-3)
    assert mf.rho_range(top) == pytest.approx((top.rho, top.rho + top.rho_slope[0]))
    # the constant fit's emulator is worse at fresh expensive runs
    constant = mf.fit_levels(xts, ys, seed=0)
    fresh = np.random.default_rng(9).uniform(size=(400, 2))
    truth = expensive(fresh[:, 0], fresh[:, 1])
    errors = [np.sqrt(np.mean((mf.predict(lv, fresh)[0] - truth) ** 2)) for lv in (levels, constant)]
    assert errors[0] < 0.6 * errors[1]  # 0.00036 against 0.00138 (seeds 5 to 8: ratios 0.26 to 0.53)


def test_gls_rho_solves_its_normal_equations():
    """gls_rho against the weighted least-squares normal equations written out."""
    xts, ys = two_level_runs(60, 15, seed=1)
    h = Hyperparameters(0.1, 0.4, np.array([0.3, 0.5]), 0.01)
    levels = mf.fit_levels(xts[:1], ys[:1], seed=0)
    levels.append(mf.Level(h, 1.0, xts[1], ys[1], np.zeros(1)))
    z = mf.mean_function(levels[:1])(xts[1])
    G = np.column_stack([z, xts[1][:, 0] * z])
    W = np.linalg.inv(run_covariance(xts[1], h))
    expected = np.linalg.solve(G.T @ W @ G, G.T @ W @ (ys[1] - h.mean))
    np.testing.assert_allclose(mf.gls_rho(levels, 1), expected, rtol=1e-6)


def test_a_cheap_level_unrelated_to_the_expensive_one_is_flagged_with_rho_of_x():
    rng = np.random.default_rng(3)
    x_low = rng.uniform(size=(30, 1))
    x_high = x_low[:8]
    low = rng.normal(size=30)  # noise: says nothing of the expensive level
    high = np.sin(6 * x_high[:, 0])
    levels = mf.fit_levels([x_low, x_high], [low, high], seed=0, slopes=1)
    value = mf.cheap_runs_value(levels)
    assert not value.helps
    assert "do not help" in value.warning() and "over the inputs' box" in value.warning()


def test_a_rho_near_zero_everywhere_is_negligible_and_a_slope_is_not():
    xts, ys = two_level_runs(40, 12, seed=2)
    h_low, h_top = (Hyperparameters(0.0, sd, np.array([0.3, 0.5]), 0.01) for sd in (0.8, 0.4))
    cheap_level = mf.Level(h_low, 1.0, xts[0], ys[0])
    small = 0.02 * h_top.sd / h_low.sd  # |rho| sd_below at most 0.04 of g_2's sd over the box (0.1 flags)
    flat = [cheap_level, mf.Level(h_top, small, xts[1], ys[1], np.array([small]))]
    assert mf.cheap_runs_value(flat).negligible == [True]
    # zero at one end of the box, large at the other: not negligible everywhere
    sloped = [cheap_level, mf.Level(h_top, 0.0, xts[1], ys[1], np.array([1.0]))]
    assert mf.cheap_runs_value(sloped).negligible == [False]


def cooling_frames(seed: int = 0) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    rng = np.random.default_rng(seed)
    physical = pd.DataFrame({"t": np.linspace(0.1, 0.9, 6), "y": np.linspace(1, 0.5, 6) + rng.normal(0, 0.01, 6)})

    def runs(n):  # the runs span the physical inputs' range
        t, k = np.linspace(0, 1, n), rng.uniform(0.5, 2, n)
        return pd.DataFrame({"t": t, "k": k, "y": np.exp(-k * t)})

    return physical, runs(20), runs(6)


def test_the_rho_form_is_checked():
    physical, low, high = cooling_frames()
    args = (physical, ["t"], "y", {"k": (0.5, 2.0)})
    data = stancal.CalibrationData(*args, runs=[low, high], low_fidelity_rho="linear")
    assert data.low_fidelity_rho == "linear"
    assert stancal.CalibrationData.from_dict(data.to_dict()).low_fidelity_rho == "linear"
    assert data.subset([0, 1, 2, 3]).low_fidelity_rho == "linear"
    with pytest.raises(DataError, match="low-fidelity rho must be one of constant, linear; got 'quadratic'"):
        stancal.CalibrationData(*args, runs=[low, high], low_fidelity_rho="quadratic")
    with pytest.raises(DataError, match="'linear' needs low-fidelity runs"):
        stancal.CalibrationData(*args, runs=high, low_fidelity_rho="linear")
    # a linear rho is learned from each upper level's runs alone (review: 3 expensive runs over 2 inputs let
    # the fit zero the level's own GP; an input they hold constant trades its slope with the intercept)
    with pytest.raises(DataError, match=r"level 2 has 3 runs \(at least 4 spread over the inputs"):
        stancal.CalibrationData(*args, runs=[low, high.iloc[:3]], low_fidelity_rho="linear")
    with pytest.raises(DataError, match=r"level 2's runs hold input\(s\) \['t'\] constant"):
        stancal.CalibrationData(*args, runs=[low, high.assign(t=high["t"].iloc[0])], low_fidelity_rho="linear")
    stancal.CalibrationData(*args, runs=[low, high.iloc[:3]])  # a constant rho needs no more
    low_own = low.rename(columns={"k": "a"})
    with pytest.raises(DataError, match="not yet available with the cheap simulator's own theta_l"):
        stancal.CalibrationData(*args, runs=[low_own, high], theta_low={"a": (0.5, 2.0)}, low_fidelity_rho="linear")


def test_a_config_reads_the_rho_form_and_refuses_an_unknown_one(tmp_path):
    physical, low, high = cooling_frames()
    physical.to_csv(tmp_path / "physical.csv", index=False)
    low.to_csv(tmp_path / "low.csv", index=False)
    high.to_csv(tmp_path / "high.csv", index=False)
    text = ('[physical]\ncsv = "physical.csv"\ninputs = ["t"]\noutput = "y"\n'
            '[simulator]\nruns = "high.csv"\n[simulator.theta]\nk = [0.5, 2.0]\n'
            '[simulator.low_fidelity]\nruns = "low.csv"\nrho = "{}"\n')
    (tmp_path / "good.toml").write_text(text.format("linear"))
    assert load_config(tmp_path / "good.toml").data.low_fidelity_rho == "linear"
    (tmp_path / "bad.toml").write_text(text.format("quadratic"))
    with pytest.raises(ConfigError, match=r"\[simulator.low_fidelity\] rho must be one of constant, linear"):
        load_config(tmp_path / "bad.toml")


def test_the_summary_and_report_give_rho_over_the_inputs():
    """rho_of_inputs (summary.json's emulator entry) and the report's lines for a linear rho."""
    from stancal.fitting.stage_one import rho_of_inputs
    from stancal.reporting.report import rho_lines

    physical, low, high = cooling_frames()
    data = stancal.CalibrationData(physical, ["t"], "y", {"k": (0.5, 2.0)}, runs=[low, high],
                                   low_fidelity_rho="linear")
    h = Hyperparameters(0.0, 1.0, np.array([0.3, 0.5]), 0.01)
    levels = [mf.Level(h, 1.0, np.zeros((3, 2)), np.zeros(3)), mf.Level(h, 0.4, np.zeros((3, 2)), np.zeros(3),
                                                                         np.array([0.8]))]
    entry = rho_of_inputs(data, levels)
    assert entry["level_rho_slope"] == [{"t": 0.8}]
    assert entry["level_rho_range"] == [pytest.approx([0.4, 1.2])]
    t_low, t_width = data.scaling.low["t"], data.scaling.width["t"]
    assert entry["level_rho_profile"][0]["inputs"]["t"] == pytest.approx(t_low + t_width * np.linspace(0, 1, 5))
    assert entry["level_rho_profile"][0]["rho"]["t"] == pytest.approx([0.4, 0.6, 0.8, 1.0, 1.2])
    text = "\n".join(rho_lines({"level_rho": [0.4], **entry}))
    assert "rho(x) = 0.4 +0.8 u_t" in text and "from 0.4 to 1.2 over the inputs' box" in text
    assert "| t | 0, 0.25, 0.5, 0.75, 1 | 0.4, 0.6, 0.8, 1, 1.2 |" in text
    constant = [levels[0], mf.Level(h, 0.4, np.zeros((3, 2)), np.zeros(3))]
    assert rho_of_inputs(data, constant) == {}
    assert rho_lines({"level_rho": [0.4]}) == ["- each level's scale on the one below: 0.4"]
    # the joint path samples rho: the number shown is stage 1's start, and the line says so
    assert "at stage 1 (the chains' start" in rho_lines({"level_rho": [0.4], "rho_sampled": True})[0]


@pytest.fixture(scope="module")
def linear_fit():
    from test_multifidelity import problem

    return fit(problem(low_fidelity_rho="linear"), method="modular", discrepancy="none", draws=1000)


@pytest.mark.slow  # one fit with its stage 1, about a minute on two shared cores
def test_modular_with_rho_of_x_matches_quadrature_of_the_same_model(linear_fit):
    """modular.stan's per-point weights against the numpy co-kriging with rho(x), by quadrature."""
    from test_multifidelity import K_TRUE, quadrature_posterior

    assert_healthy(linear_fit)
    levels = fidelity_levels(linear_fit.data, linear_fit.emulator["hyperparameters"]["levels"])
    assert len(levels[1].rho_slope) == 1  # the quadrature below uses the slope stage 1 found
    mean, sd = quadrature_posterior(linear_fit.data, levels)
    k = np.asarray(linear_fit.idata["posterior"]["theta"]).reshape(-1)
    # the same tolerances as the constant rho's test (tests/test_multifidelity.py)
    assert abs(k.mean() - mean) < 0.2 * sd, (k.mean(), mean, sd)
    assert k.std() == pytest.approx(sd, rel=0.15)
    assert abs(mean - K_TRUE) < 3 * sd


@pytest.mark.slow
def test_the_summary_json_and_report_of_a_fit_show_rho_of_x(linear_fit, tmp_path):
    emulator = linear_fit.to_summary_json()["emulator"]
    assert len(emulator["level_rho_slope"]) == 1 and "t" in emulator["level_rho_profile"][0]["rho"]
    stancal.write_calibration(linear_fit, tmp_path)
    assert "linear in the inputs: rho(x) =" in (tmp_path / "report.md").read_text()
