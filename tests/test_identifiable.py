"""Identifiable calibration (review section 6): L2 calibration, orthogonal GP,
scaled GP and `stancal compare`."""

import json
import sys

import numpy as np
import pandas as pd
import pytest
from conftest import COOLING, K_TRUE, ROOT, assert_healthy, fit, newton, no_stancal_warnings
from scipy import optimize

import stancal
from stancal.cli import main
from stancal.diagnosing.compare import METHODS, compare_methods, discrepancy_rms
from stancal.fitting.l2 import project
from stancal.numerics.quadrature import input_box_quadrature
from stancal.reporting.compare_report import write_comparison

sys.path.insert(0, str(ROOT / "case_studies" / "tuo_wu"))
import tuo_wu  # noqa: E402

TUO_WU = ROOT / "case_studies" / "tuo_wu"
SEEDS = (1, 2, 3, 4, 5)
# 3,200 draws to project per seed; R-hat within a mode was 1.025 at 4 x (300 + 150) and
# 1.026 (delta's length scale) at 4 x (300 + 400)
SETTINGS = {"chains": 4, "warmup": 400, "draws": 800}


@pytest.fixture(scope="module")
def theta_star():
    return tuo_wu.l2_projection()


def compare_on_tuo_wu(seed):
    # the orthogonal GP holds at every stationary point of the L2 loss: its
    # posterior is multimodal by design, and the fit must say so
    with pytest.warns(stancal.MultimodalWarning, match="weighted by its posterior mass"):
        return compare_methods(tuo_wu.problem(seed), simulator=tuo_wu.SIMULATOR,
                               methods=("koh", "l2", "orthogonal"), seed=seed, **SETTINGS)


def assert_comparison_healthy(comparison):
    """Every method that sampled (l2 projects koh's draws: its diagnostics are koh's). The
    orthogonal GP's posterior is multimodal by design, and its R-hat is taken within each mode
    from the one or two chains there (a single chain as its two halves): at 800 draws a chain
    it measured 1.011 to 1.026 over runs, so its bar is 1.03; koh keeps 1.01."""
    for method in comparison.fits:
        if method.result is not None:
            assert_healthy(method.result, rhat=1.03 if method.name == "orthogonal" else 1.01)


def brute_force_projection(result, quadrature, simulator, lower, upper, grid_points=2001):
    """The L2 projection of each zeta draw, by brute force: the loss on a
    grid over the theta box (a numpy simulator, not the fit's), then a
    bounded scalar search in the best cell. Returns (theta, rms) per draw."""
    from scipy.optimize import minimize_scalar

    r = len(quadrature.weights)
    zeta = np.asarray(result.idata["predictions"]["zeta_new"])[..., -r:].reshape(-1, r)
    grid = np.linspace(lower, upper, grid_points)
    f = simulator(quadrature.nodes, grid)  # (grid, nodes)
    losses = ((zeta**2) @ quadrature.weights)[:, None] - 2 * (zeta * quadrature.weights) @ f.T \
        + ((f**2) @ quadrature.weights)[None, :]
    step = grid[1] - grid[0]
    theta, rms = np.empty(len(zeta)), np.empty(len(zeta))
    for d, row in enumerate(zeta):
        best = grid[np.argmin(losses[d])]
        def loss(t, row=row):
            return quadrature.mean_square(row - simulator(quadrature.nodes, [t])[0])

        search = minimize_scalar(loss,
                                 bounds=(max(lower, best - step), min(upper, best + step)), method="bounded",
                                 options={"xatol": 1e-10})
        theta[d], rms[d] = search.x, np.sqrt(search.fun)
    return theta, rms


def tuo_wu_at(nodes, theta):
    return tuo_wu.simulator(nodes["x"].to_numpy()[None, :], np.asarray(theta, float)[:, None])


def cooling_at(nodes, theta):
    t, T0 = nodes["t"].to_numpy(), nodes["T0"].to_numpy()
    return np.array([newton(t, T0, k) for k in np.asarray(theta, float)])


@pytest.fixture(scope="module")
def tuo_wu_seed_1():
    return compare_on_tuo_wu(1)


@pytest.fixture(scope="module")
def tuo_wu_comparisons(tuo_wu_seed_1):
    """koh, l2 and orthogonal on the review's example with five noise seeds."""
    return {1: tuo_wu_seed_1, **{seed: compare_on_tuo_wu(seed) for seed in SEEDS[1:]}}


def _estimates(comparisons, method):
    return {seed: c.table().loc[method, "theta_q50"] for seed, c in comparisons.items()}


def _mode_nearest(comparison, theta_star):
    """The orthogonal GP's theta mode nearest theta*: (its mean, its weight)."""
    result = next(f.result for f in comparison.fits if f.name == "orthogonal")
    mode = min(result.modes, key=lambda m: abs(m.theta_mean["theta"] - theta_star))
    return mode.theta_mean["theta"], (mode.weight if len(result.modes) > 1 else 1.0)


@pytest.mark.slow  # 95 s: the default run stays within 12 minutes; the five-seed study below holds the bar
def test_tuo_wu_one_seed(tuo_wu_seed_1, theta_star):
    """One seed of the review's example (the five-seed study below): L2 within 0.12 of theta* (the estimator's own noise over seeds is
    about 0.04), and theta* among the orthogonal GP's modes with a real share
    of the mass."""
    assert_comparison_healthy(tuo_wu_seed_1)
    l2 = tuo_wu_seed_1.table().loc["l2", "theta_q50"]
    assert abs(l2 - theta_star) < 0.12
    theta, weight = _mode_nearest(tuo_wu_seed_1, theta_star)
    assert abs(theta - theta_star) < 0.12 and weight > 0.2


@pytest.mark.slow  # 15 fits
def test_tuo_wu_l2_finds_the_l2_projection(tuo_wu_comparisons, theta_star):
    """The issue's bar: the mean over 5 seeds within 0.03 of theta*, each seed
    within 0.12 (the estimator's own noise is about 0.04)."""
    for comparison in tuo_wu_comparisons.values():
        assert_comparison_healthy(comparison)
    estimates = _estimates(tuo_wu_comparisons, "l2")
    koh = _estimates(tuo_wu_comparisons, "koh")
    print("\nl2: " + ", ".join(f"seed {s}: {v:.4f}" for s, v in estimates.items())
          + f"; mean {np.mean(list(estimates.values())):.4f} (theta* {theta_star:.4f})")
    print("koh: " + ", ".join(f"seed {s}: {v:.4f}" for s, v in koh.items())
          + f"; mean {np.mean(list(koh.values())):.4f} (the review: KOH -0.0821, L2 -0.1844)")
    assert abs(np.mean(list(estimates.values())) - theta_star) < 0.03
    assert all(abs(v - theta_star) < 0.12 for v in estimates.values())


@pytest.mark.slow  # shares the 15 fits above
def test_tuo_wu_orthogonal_has_a_mode_at_the_l2_projection(tuo_wu_comparisons, theta_star):
    """The orthogonal GP holds at every stationary point of the L2 loss, so its
    posterior is multimodal and weighed by mass (issue 12, item 6); theta* is
    one of its modes in every seed, with a real share of the mass, and that
    mode's mean over seeds is within 0.03 of theta*."""
    for comparison in tuo_wu_comparisons.values():
        assert_comparison_healthy(comparison)
    nearest = {seed: _mode_nearest(c, theta_star) for seed, c in tuo_wu_comparisons.items()}
    print("\northogonal, mode nearest theta* (theta, weight): "
          + ", ".join(f"seed {s}: {t:.4f}, {w:.2f}" for s, (t, w) in nearest.items()))
    assert abs(np.mean([t for t, _ in nearest.values()]) - theta_star) < 0.03
    assert all(abs(t - theta_star) < 0.12 and w > 0.2 for t, w in nearest.values())


@pytest.mark.slow  # shares the 15 fits above
def test_tuo_wu_l2_interval_and_discrepancy(tuo_wu_comparisons, theta_star):
    """The projected draws give an interval around theta*, and each draw's
    projection is the brute-force minimiser of the discrepancy norm (numpy
    simulator on a 2,001-point grid over [-2, 2], then a bounded search:
    the global minimum, not a local one), and the table's ELPD is ArviZ's
    PSIS-LOO of the fit's own log-likelihood."""
    import arviz_stats

    covered = 0
    for comparison in tuo_wu_comparisons.values():
        assert_comparison_healthy(comparison)
        table = comparison.table()
        covered += table.loc["l2", "theta_q05"] < theta_star < table.loc["l2", "theta_q95"]
        l2 = next(f.result for f in comparison.fits if f.name == "l2")
        _, rms = brute_force_projection(l2, comparison.quadrature, tuo_wu_at, -2.0, 2.0)
        # the norm at the reported theta equals the global minimum (the loss is multimodal, so
        # two basins may tie within the tolerance: theta itself is compared on the unimodal
        # cooling problem below); 1e-6 relative: Gauss-Newton stops at steps of 1e-7 of the box
        np.testing.assert_allclose(discrepancy_rms(l2, comparison.quadrature), rms, rtol=1e-6, atol=1e-9)
        for method in ("koh", "l2"):
            result = next(f.result for f in comparison.fits if f.name == method)
            reference = arviz_stats.loo(result.idata)
            # 0.05: the bar the old l2-against-koh check used for differing PSIS relative
            # efficiency estimates (not re-measured)
            assert table.loc[method, "elpd"] == pytest.approx(float(reference.elpd), abs=0.05), method
    assert covered >= 4


def test_l2_predictions_use_the_projected_theta(exact_comparison):
    """The L2 fit's simulator curve is Newton's law (numpy) at its projected
    k, draw by draw; the comparison's fit serves (the Tuo & Wu fit this test
    read before is a slow study now)."""
    comparison, _ = exact_comparison
    assert_comparison_healthy(comparison)
    result = next(f.result for f in comparison.fits if f.name == "l2")
    points = pd.DataFrame({"t": [0.5, 10.0, 40.0], "T0": [95.0, 80.0, 60.0]})
    table = result.predict(points)
    f = cooling_at(points, result.theta_draws()["k"].to_numpy())  # (draws, points)
    np.testing.assert_allclose(table["f_q50"], np.median(f, axis=0), rtol=1e-8)
    # the medians of f and of delta need not add up to zeta's exactly; the discrepancy is far
    # below the noise here (sd 0.3), so they agree to a tenth of it
    np.testing.assert_allclose(table["delta_q50"] + table["f_q50"], table["zeta_q50"], atol=0.03)


def test_projection_searches_globally(theta_star):
    """The Tuo & Wu loss has local minima at -0.68, 0.50 and 0.92 besides
    theta*: a local optimiser started at 0.3 ends at 0.50; the projection,
    started nowhere in particular, finds theta*."""
    data = tuo_wu.problem(1)
    quadrature = input_box_quadrature(data)
    x = quadrature.nodes["x"].to_numpy()

    def simulator(points, theta):
        return tuo_wu.simulator(points["x"].to_numpy()[None, :], np.atleast_2d(theta)[:, :1])

    def loss(t):
        return quadrature.mean_square(tuo_wu.zeta(x) - tuo_wu.simulator(x, t[0]))

    local = optimize.minimize(loss, [0.3], bounds=[(-2, 2)]).x[0]
    assert abs(local - 0.50) < 0.02  # the trap
    projection = project(tuo_wu.zeta(x)[None, :], quadrature, simulator, np.array([-2.0]), np.array([2.0]))
    assert projection.theta[0, 0] == pytest.approx(theta_star, abs=2e-3)  # 48-node quadrature error
    assert projection.runner_up_loss[0] > projection.loss[0]


def compared(exact_cooling_data, tmp_path_factory, methods):
    data = stancal.CalibrationData(exact_cooling_data.physical, ["t", "T0"], "temperature",
                                   {"k": (0.01, 0.2)})
    out = tmp_path_factory.mktemp("compare")
    # koh's R-hat was above 1.01 at 2 x (300 + 300) and 1.014 at 4 x (300 + 300). The effective
    # sample size may stay below the library's bar of 100 per chain in the orthogonal fit's tail
    # (319 of 400 at 4 x 300): allowed here, as every method's health is asserted by the tests
    with no_stancal_warnings(allow="effective sample size down to"):
        comparison = compare_methods(data, simulator=COOLING / "simulator.stan", seed=3, methods=methods,
                                     out_dir=out, chains=4, warmup=300, draws=700)
    return comparison, out


@pytest.fixture(scope="module")
def exact_comparison(exact_cooling_data, tmp_path_factory):
    """koh and l2 alone: l2 projects koh's draws, so one fit (the four methods' fixture took about 150 s)."""
    return compared(exact_cooling_data, tmp_path_factory, ("koh", "l2"))


@pytest.fixture(scope="module")
def every_method_comparison(exact_cooling_data, tmp_path_factory):
    return compared(exact_cooling_data, tmp_path_factory, METHODS)


@pytest.mark.slow  # four methods' fits, about 150 s; the default run compares koh and l2 (exact_comparison)
def test_every_method_recovers_an_exact_simulator(every_method_comparison):
    """On this dataset least squares gives k = 0.05047 +- 0.00015, 3 se from the
    truth 0.05 (issue 2): each method's interval must hold the least-squares
    estimate, its median be within 1 % of the truth, and the discrepancy
    be far below the noise (sd 0.3)."""
    comparison, out = every_method_comparison
    assert_comparison_healthy(comparison)
    table = comparison.table()
    print("\n" + table[["k_q05", "k_q50", "k_q95", "discrepancy_rms_q50", "elpd"]].to_string())
    k_ls = least_squares_k(comparison.fits[0].result.data.physical)
    assert list(table.index) == ["koh", "l2", "orthogonal", "scaled"]
    for method, row in table.iterrows():
        assert row["k_q05"] < k_ls < row["k_q95"], method
        assert abs(row["k_q50"] - K_TRUE) < 0.01 * K_TRUE, method
        assert row["discrepancy_rms_q50"] < 0.15, method
    summary = write_comparison(comparison, out)
    assert {"comparison.csv", "comparison.json", "comparison.png", "report.md", "report.html"} <= \
        {p.name for p in out.iterdir()}
    assert len(summary["methods"]) == 4
    assert (out / "scaled" / "posterior.nc").exists()


def least_squares_k(physical: pd.DataFrame) -> float:
    """The least-squares k of Newton's law on the readings: the reference an exact simulator's posterior holds."""
    (k_ls,), _ = optimize.curve_fit(lambda X, k: newton(X[0], X[1], k), physical[["t", "T0"]].to_numpy().T,
                                    physical["temperature"].to_numpy(), p0=[0.06])
    return float(k_ls)


@pytest.mark.slow  # the default run's 12-minute budget (docs/validation.md)
def test_l2_from_simulator_runs_uses_the_emulator(exact_cooling_data):
    """Without a Stan simulator, L2 projects koh_emulator's zeta onto the
    emulator's mean: its interval holds the least-squares k (0.05047, 3 se
    from the truth on these readings), as the comparison's methods do."""
    # the emulator mean's R-hat was 1.027 at 2 x (300 + 150) and 1.0106 at 4 x (300 + 300). Every
    # gradient factors the (points + runs)-square covariance: every other run of the 60 (their range
    # still spans the readings') took this test from 105 s to 25 s
    data = exact_cooling_data.with_runs(exact_cooling_data.runs.iloc[::2])
    result = fit(data, method="l2", chains=4, warmup=400, draws=700)
    assert_healthy(result)
    assert result.l2["base_method"] == "koh_emulator"
    s = result.theta_summary()["k"]
    assert s["q05"] < least_squares_k(data.physical) < s["q95"]
    # measured 0.0031 wide (sd 0.0013, against least squares' 0.00015: the emulator's uncertainty); the prior's 0.17
    assert s["q95"] - s["q05"] < 0.01


def test_l2_projection_minimises_the_discrepancy_norm(exact_comparison):
    """Per draw, the projected theta is the brute-force minimiser of the
    discrepancy norm over the k box (Newton's law in numpy on a 2,001-point
    grid over [0.01, 0.2], then a bounded search in the best cell), and the
    norm reported for it is that minimum."""
    comparison, _ = exact_comparison
    assert_comparison_healthy(comparison)
    l2 = next(f.result for f in comparison.fits if f.name == "l2")
    theta, rms = brute_force_projection(l2, comparison.quadrature, cooling_at, 0.01, 0.2)
    # 1e-6 in k, against a posterior sd of 1.5e-4: Gauss-Newton stops at steps below 1e-7 of the
    # box (1.9e-8), the bounded search at 1e-10
    np.testing.assert_allclose(l2.theta_draws()["k"].to_numpy(), theta, atol=1e-6)
    np.testing.assert_allclose(discrepancy_rms(l2, comparison.quadrature), rms, rtol=1e-6, atol=1e-9)


def test_cli_compare_and_l2(tmp_path, capsys):
    # health not asserted: 2 x 100 draws check the command's files and fields, no statistical claim
    code = main(["compare", str(TUO_WU / "config.toml"), "--out", str(tmp_path / "cmp"), "--chains", "2",
                 "--warmup", "200", "--draws", "100", "--seed", "1", "--methods", "koh", "l2", "scaled"])
    assert code == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    assert "l2: theta = " in printed and "scaled: theta = " in printed
    summary = json.loads((tmp_path / "cmp" / "comparison.json").read_text())
    assert [m["method"] for m in summary["methods"]] == ["koh", "l2", "scaled"]
    l2_summary = json.loads((tmp_path / "cmp" / "l2" / "summary.json").read_text())
    assert l2_summary["method"] == "l2" and l2_summary["l2"]["base_method"] == "koh"
    code = main(["calibrate", str(TUO_WU / "config.toml"), "--out", str(tmp_path / "l2"), "--method", "l2",
                 "--chains", "2", "--warmup", "200", "--draws", "100", "--seed", "1"])
    assert code == 0
    assert json.loads((tmp_path / "l2" / "summary.json").read_text())["method"] == "l2"


def test_bad_requests_name_the_problem(exact_cooling_data, tmp_path, capsys):
    with pytest.raises(ValueError, match="orthogonal.*needs method 'koh'"):
        stancal.calibrate(exact_cooling_data, method="koh_emulator", discrepancy="orthogonal")
    covariate = exact_cooling_data.physical.assign(humidity=np.linspace(30, 70, 24))
    with_covariate = stancal.CalibrationData(covariate, ["t", "T0"], "temperature", {"k": (0.01, 0.2)},
                                             covariates=["humidity"])
    with pytest.raises(ValueError, match=r"cannot take the covariates \['humidity'\]"):
        stancal.calibrate(with_covariate, simulator=COOLING / "simulator.stan", discrepancy="orthogonal")
    with pytest.raises(ValueError, match=r"cannot take the covariates \['humidity'\]"):
        stancal.calibrate(with_covariate, simulator=COOLING / "simulator.stan", method="l2")
    with pytest.raises(ValueError, match="scaled_lambda must be a positive number"):
        stancal.calibrate(exact_cooling_data, simulator=COOLING / "simulator.stan", discrepancy="scaled",
                          scaled_lambda=-1)
    with pytest.raises(ValueError, match="discrepancy must be one of"):
        stancal.calibrate(exact_cooling_data, simulator=COOLING / "simulator.stan", discrepancy="bogus")
    with pytest.raises(ValueError, match="unknown methods"):
        compare_methods(exact_cooling_data, methods=("koh", "magic"))
    config = tmp_path / "config.toml"
    config.write_text((TUO_WU / "config.toml").read_text().replace('discrepancy = "gp"', 'discrepancy = "scaled"\n'
                                                                  'scaled_lambda = 0'))
    for name in ("physical.csv", "simulator.stan"):
        (tmp_path / name).write_text((TUO_WU / name).read_text())
    assert main(["calibrate", str(config), "--out", str(tmp_path / "out")]) == 2
    assert "scaled_lambda must be a positive number" in capsys.readouterr().err
