"""The design loop on every kind of calibration config with runs
(docs/design.md, "Any config with runs"): counts matched on the link scale,
censored rows one-sided, theta per experiment in NROY's space; and the
posterior criterion's emulator. No Stan: the emulators are numpy GPs."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import direct_theta_trace
from scipy.stats import qmc

import stancal
from stancal.designing.emulators import GaussianProcess, ScalarEmulator, calibration_emulator
from stancal.designing.implausibility import Cut
from stancal.designing.targets import DesignSettings, UnitBox, targets_of
from stancal.numerics.scalable_emulator import Hyperparameters
from stancal.problem.vector_data import VectorCalibrationData

RATE_TRUTH = {"a": 3.0, "b": 0.8}  # 20 to 45 counts


def rate(frame: pd.DataFrame) -> np.ndarray:
    """A count simulator's mean: exp(a + b x) counts (log link)."""
    return np.exp(frame["a"] + frame["b"] * frame["x"]).to_numpy()


def runs_table(runs: int, seed: int, bounds: dict) -> pd.DataFrame:
    low, high = zip(*([(0.0, 1.0)] + list(bounds.values())), strict=True)
    unit = qmc.LatinHypercube(d=len(low), seed=seed).random(runs)
    table = pd.DataFrame(qmc.scale(unit, low, high), columns=["x", *bounds])
    table.loc[:1, "x"] = [0.0, 1.0]
    return table


def count_data(likelihood: str = "poisson", runs: int = 30, seed: int = 1) -> stancal.CalibrationData:
    x = np.linspace(0, 1, 12) ** 1.5  # gaps that grow: each value's nearest neighbour is the one before it
    physical = pd.DataFrame({"x": x})
    mean = rate(physical.assign(**RATE_TRUTH))
    rng = np.random.default_rng(seed)
    bounds = {"a": (1.0, 4.0), "b": (0.0, 2.0)}
    table = runs_table(runs, seed, bounds)
    if likelihood == "binomial":
        probability = mean / (1 + mean)  # logit p = a + b x
        physical["n"] = 40
        physical["y"] = rng.binomial(40, probability)
        table["y"] = rate(table) / (1 + rate(table))
        return stancal.CalibrationData(physical, ["x"], "y", bounds, runs=table, likelihood="binomial", trials="n")
    physical["y"] = rng.poisson(mean) if likelihood == "poisson" else rng.negative_binomial(5, 5 / (5 + mean))
    table["y"] = rate(table)
    return stancal.CalibrationData(physical, ["x"], "y", bounds, runs=table, likelihood=likelihood)


def hand_emulator(center: float = 1.5) -> ScalarEmulator:
    h = Hyperparameters(mean=0.0, sd=1.1, length_scale=np.array([0.6, 0.5, 0.7]), nugget=0.01)
    xt = np.random.default_rng(7).uniform(size=(6, 3))
    return ScalarEmulator(GaussianProcess(h, xt, np.sin(3 * xt.sum(axis=1))), center=center, scale=0.8)


# ---- counts ---------------------------------------------------------------------------
def test_poisson_counts_are_matched_on_the_log_scale_with_the_delta_method_variance():
    """z = log(y + 1/2), its variance 1 / (y + 1/2) (Cox 1970): I at a theta
    by hand from the emulator's mean and variance on the log scale."""
    data = count_data("poisson")
    y = data.physical["y"].to_numpy(float)
    targets = targets_of(data, DesignSettings(discrepancy_sd=0.1))
    np.testing.assert_allclose(targets.z, np.log(y + 0.5))
    np.testing.assert_allclose(targets.noise_variance, 1 / (y + 0.5))
    assert targets.noise_source.startswith("the poisson model's variance")
    emulator = hand_emulator()
    theta = np.array([[0.3, 0.6]])
    mean, variance = emulator.at(targets.x_unit, theta)
    expected = np.abs(np.log(y + 0.5) - mean[0]) / np.sqrt(variance[0] + 0.1**2 + 1 / (y + 0.5))
    np.testing.assert_allclose(Cut(emulator, targets, 1, 3.0).each(theta)[0], expected, rtol=1e-12)
    # a given noise_sd adds to the count model's variance (on the log scale)
    wider = targets_of(data, DesignSettings(noise_sd=0.2))
    np.testing.assert_allclose(wider.noise_variance, 1 / (y + 0.5) + 0.04)


def test_binomial_successes_are_matched_on_the_logit_scale():
    """The empirical logit log((y + 1/2) / (n - y + 1/2)), its variance
    1 / (y + 1/2) + 1 / (n - y + 1/2) (Gart & Zweifel 1967)."""
    data = count_data("binomial")
    y = data.physical["y"].to_numpy(float)
    targets = targets_of(data, DesignSettings())
    np.testing.assert_allclose(targets.z, np.log((y + 0.5) / (40 - y + 0.5)))
    np.testing.assert_allclose(targets.noise_variance, 1 / (y + 0.5) + 1 / (40 - y + 0.5))
    assert targets.discrepancy_variance == pytest.approx((0.1 * np.std(targets.z)) ** 2)


def test_a_negative_binomials_overdispersion_is_estimated_beyond_the_count_part():
    data = count_data("negbinomial")
    y = data.physical["y"].to_numpy(float)
    targets = targets_of(data, DesignSettings())
    z = np.log(y + 0.5)
    neighbour = np.array([1, *range(11)])
    rice = np.mean((z - z[neighbour]) ** 2) / 2
    extra = max(rice - np.mean(1 / (y + 0.5)), 0.0)
    np.testing.assert_allclose(targets.noise_variance, 1 / (y + 0.5) + extra)
    assert targets.noise_estimated and "less the count model's" in targets.noise_source
    given = targets_of(data, DesignSettings(noise_sd=0.3))  # 1 / sqrt(phi)
    np.testing.assert_allclose(given.noise_variance, 1 / (y + 0.5) + 0.09)


def test_waves_on_counts_emulate_the_link_scale_and_keep_the_truth():
    data = count_data("poisson", runs=20)
    loop = stancal.run_waves(data, simulator=rate, waves=2, runs_per_wave=8, seed=1,
                             settings=DesignSettings(discrepancy_sd=0.05, nroy_points=1000))
    last = loop.designs[-1].match
    emulator = last.cuts[0].emulator  # wave 1's: every run, on the log scale
    assert emulator.center == pytest.approx(np.log(loop.data.runs["y"].to_numpy()[:20]).mean())
    assert last.implausibility(pd.DataFrame([RATE_TRUTH]))[0] <= 3.0
    assert loop.fractions[-1] < 0.2  # 12 counts of a few dozen pin (a, b) down to a ridge


# ---- censored rows --------------------------------------------------------------------
def censored_data() -> stancal.CalibrationData:
    """The toy f = a sin(3x) + b x (truth a = 0.6, b = -0.4): rows 6 and 7
    below a detection limit of 0 (left-censored; -0.02 and -0.32 in truth),
    row 3 above a saturation of 0.38 (right-censored; 0.41)."""
    x = np.linspace(0, 1, 8)
    y = 0.6 * np.sin(3 * x) - 0.4 * x + np.random.default_rng(1).normal(0, 0.02, 8)
    physical = pd.DataFrame({"x": x, "y": y, "low": np.nan, "high": np.nan})
    physical.loc[[6, 7], ["y", "high"]] = [np.nan, 0.0]
    physical.loc[3, ["y", "low"]] = [np.nan, 0.38]
    table = runs_table(30, 1, {"a": (0.0, 1.0), "b": (-1.0, 1.0)})
    table["y"] = table["a"] * np.sin(3 * table["x"]) + table["b"] * table["x"]
    return stancal.CalibrationData(physical, ["x"], "y", {"a": (0.0, 1.0), "b": (-1.0, 1.0)}, runs=table,
                                   lower="low", upper="high")


def test_a_censored_row_is_implausible_only_beyond_its_bound_on_the_wrong_side():
    data = censored_data()
    targets = targets_of(data, DesignSettings(noise_sd=0.02, discrepancy_sd=0.05))
    assert np.isnan(targets.z[[3, 6, 7]]).all() and targets.observed.sum() == 5
    emulator = hand_emulator(center=0.0)
    theta = np.random.default_rng(2).uniform(size=(50, 2))
    mean, variance = emulator.at(targets.x_unit, theta)
    sd = np.sqrt(variance + 0.05**2 + 0.02**2)
    each = Cut(emulator, targets, 1, 3.0).each(theta)
    y = data.physical["y"].to_numpy()
    for i in (0, 1, 2, 4, 5):
        np.testing.assert_allclose(each[:, i], np.abs(y[i] - mean[:, i]) / sd[:, i], rtol=1e-12)
    for i in (6, 7):  # known to be at most 0: only a mean above it counts
        np.testing.assert_allclose(each[:, i], np.maximum(mean[:, i] - 0.0, 0) / sd[:, i], rtol=1e-12)
    np.testing.assert_allclose(each[:, 3], np.maximum(0.38 - mean[:, 3], 0) / sd[:, 3], rtol=1e-12)
    for i in (3, 6, 7):  # both sides of each bound are reached
        assert (each[:, i] == 0).any() and (each[:, i] > 0).any()
    # the noise estimate and the discrepancy's default use the observed rows only
    default = targets_of(data, DesignSettings())
    assert default.discrepancy_variance == pytest.approx((0.1 * np.std(y[~np.isnan(y)])) ** 2)


def test_waves_on_censored_rows_keep_the_truth():
    data = censored_data()

    def simulator(frame):
        return (frame["a"] * np.sin(3 * frame["x"]) + frame["b"] * frame["x"]).to_numpy()

    loop = stancal.run_waves(data, simulator=simulator, waves=2, runs_per_wave=6, seed=2,
                             settings=DesignSettings(noise_sd=0.02, nroy_points=1000))
    match = loop.designs[-1].match
    assert match.implausibility(pd.DataFrame([{"a": 0.6, "b": -0.4}]))[0] <= 3.0
    assert match.nroy_fraction < 0.2


# ---- theta per experiment -------------------------------------------------------------
PER_EXPERIMENT_TRUTH = {"a": 2.0, "b": {"e1": 0.5, "e2": 1.5, "e3": 2.5}}
GRID = np.linspace(0, 2, 9)


def decay(frame: pd.DataFrame) -> np.ndarray:
    """(runs, 9): a exp(-b t) + x on the grid of t."""
    a, b, x = (frame[c].to_numpy()[:, None] for c in ("a", "b", "x"))
    return a * np.exp(-b * GRID[None, :]) + x


def per_experiment_data(runs: int = 40) -> stancal.VectorCalibrationData:
    """Three experiments, each with its own decay rate b (per experiment),
    a shared amplitude a."""
    rng = np.random.default_rng(3)
    rows = []
    for e, x in zip(PER_EXPERIMENT_TRUTH["b"], (0.0, 0.5, 1.0), strict=True):
        setting = pd.DataFrame({"x": [x], "a": [PER_EXPERIMENT_TRUTH["a"]], "b": [PER_EXPERIMENT_TRUTH["b"][e]]})
        y = decay(setting)[0] + rng.normal(0, 0.02, len(GRID))
        rows.append(pd.DataFrame({"shot": e, "x": x, "t": GRID, "y": y, "sd": 0.02}))
    table = runs_table(runs, 4, {"a": (1.0, 3.0), "b": (0.2, 3.0)})
    long = [pd.DataFrame({"run": i, "x": r.x, "a": r.a, "b": r.b, "t": GRID, "y": decay(pd.DataFrame([r]))[0]})
            for i, r in enumerate(table.itertuples())]
    return VectorCalibrationData(pd.concat(rows, ignore_index=True), "shot", ["x"], "y", "t", {"a": (1.0, 3.0)},
                                         theta_per_experiment={"b": (0.2, 3.0)}, runs=pd.concat(long, ignore_index=True), run="run",
                                         noise_sd="sd")


def test_theta_per_experiment_matches_each_experiment_at_its_own_theta():
    data = per_experiment_data()
    box = UnitBox.of(data)
    assert box.columns == ["x", "a", "b"] and box.nroy_names == ["a", "b[e1]", "b[e2]", "b[e3]"]
    match = stancal.history_match(data, settings=DesignSettings(discrepancy_sd=0.05, nroy_points=1000), seed=1)
    assert list(match.nroy_frame().columns) == box.nroy_names
    cut = match.cuts[-1]
    joint = np.random.default_rng(5).uniform(size=(20, 4))
    each = cut.each(joint)
    for e, (row, values, indices) in enumerate(cut.targets.groups):  # experiment e at (a, b[e])
        mean, variance = cut.emulator.at(cut.targets.x_unit, joint[:, [0, 1 + e]], [(row, values, indices)])
        t = cut.targets
        expected = np.abs(t.z[values] - mean[:, values]) / np.sqrt(
            variance[:, values] + t.discrepancy_variance + t.noise_variance[values])
        np.testing.assert_allclose(each[:, values], expected, rtol=1e-12)
    truth = {"a": 2.0, **{f"b[{e}]": b for e, b in PER_EXPERIMENT_TRUTH["b"].items()}}
    assert match.implausibility(pd.DataFrame([truth]))[0] <= 3.0
    swapped = {**truth, "b[e1]": 2.5, "b[e3]": 0.5}  # each experiment's rate at another's
    assert match.implausibility(pd.DataFrame([swapped]))[0] > 3.0


def test_theta_per_experiment_runs_waves_and_writes_its_folder(tmp_path):
    from stancal.reporting.design_report import write_design

    data = per_experiment_data(runs=30)

    def simulator(frame):
        return decay(frame)

    loop = stancal.run_waves(data, simulator=simulator, waves=2, runs_per_wave=8, seed=1,
                             settings=DesignSettings(discrepancy_sd=0.05, nroy_points=1000))
    last = loop.designs[-1]
    assert list(last.next_runs.columns) == ["x", "a", "b"]
    assert (last.match.implausibility_at_runs(last.next_runs) <= 3.0).all()
    # NROY is nested (every earlier cut holds): its points pass wave 1's cut, and its estimated fraction
    # grows by no more than the estimate's noise (here the checked wave-2 emulator cuts little more)
    first = loop.designs[0].match.cuts[0]
    assert (first(last.match.nroy.theta_unit) <= 3.0).all()
    assert loop.fractions[-1] < loop.fractions[0] * (1 + 3 * last.match.nroy.fraction_cv)
    write_design(last, tmp_path / "design")
    assert list(pd.read_csv(tmp_path / "design" / "nroy.csv").columns) == ["a", "b[e1]", "b[e2]", "b[e3]"]
    assert list(pd.read_csv(tmp_path / "design" / "next_runs.csv").columns) == ["x", "a", "b"]


@pytest.fixture(scope="module")
def per_experiment_match():
    return stancal.history_match(per_experiment_data(), settings=DesignSettings(discrepancy_sd=0.05, nroy_points=1000),
                                 seed=1)


def per_experiment_gradient(cut, x: np.ndarray, groups, theta: np.ndarray, step: float = 1e-3) -> np.ndarray:
    """d mean / d theta (values, Q) at one point ``theta`` of the runs' (a, b),
    by central differences, experiment by experiment."""
    columns = []
    for q in range(len(theta)):
        up, down = theta.copy(), theta.copy()
        up[q], down[q] = min(theta[q] + step, 1), max(theta[q] - step, 0)
        means = [np.concatenate([cut.emulator.at(x, t[None], [g])[0][0, g[1]] for g in groups]) for t in (up, down)]
        columns.append((means[0] - means[1]) / (up[q] - down[q]))
    return np.column_stack(columns)


def test_next_experiments_with_theta_per_experiment_count_the_new_experiments_own_theta(per_experiment_match):
    """A new experiment brings its own rate b_new: the criterion is the
    variance of the shared a with every rate, b_new among them, unknown.
    Computed here directly, for the first pick: J = 12 I + G' V^-1 G over
    (a, b[e1], b[e2], b[e3], b_new) from every value, old and new, at once
    (no Schur complements), its inverse's (a, a) entry, averaged over the
    16 NROY draws. Counting the new values' information on a alone (b_new
    known) would give a smaller variance: the test tells them apart."""
    from stancal.designing.experiments import DISCREPANCY_LENGTH, discrepancy_covariance, index_range, positions

    match = per_experiment_match
    settings = stancal.propose_experiments(match, 2, seed=4)
    trace = settings.attrs["theta_variance_trace"]
    assert list(settings.columns) == ["x"] and settings["x"].between(0, 1).all() and trace[1] <= trace[0]
    cut, t = match.cuts[-1], match.cuts[-1].targets
    rng = np.random.default_rng(4)  # the draws next_experiments takes, in its order
    theta = match.nroy.theta_unit[rng.choice(len(match.nroy.theta_unit), 16, replace=False)]
    qmc.LatinHypercube(d=1, seed=rng).random(300)
    new_own = theta[np.arange(16), 1 + rng.integers(0, 3, 16)]  # b_new: a random experiment's rate, per draw
    new_x = match.box.inputs_to_unit(settings.iloc[:1])
    new_group = [(new_x[0], slice(0, 9), GRID[:, None])]
    x = np.vstack([t.x_unit, np.repeat(new_x, 9, axis=0)])
    groups = [*t.groups, (new_x[0], slice(t.count, t.count + 9), GRID[:, None])]
    low, width = index_range(t)
    where = positions(x, groups, low, width)
    known_variance = np.mean([t.emulate(cut.emulator, d)[1][0] for d in theta], axis=0)
    new_variance = np.mean([cut.emulator.at(new_x.repeat(9, 0), np.array([[d[0], b]]), new_group)[1][0]
                            for d, b in zip(theta, new_own, strict=True)], axis=0)
    noise = t.noise_variance.mean()
    V = discrepancy_covariance(cut, where, where, DISCREPANCY_LENGTH) + np.diag(
        np.concatenate([known_variance, new_variance]) + noise)
    with_nuisance, b_new_known = [], []
    for d, b in zip(theta, new_own, strict=True):
        G = np.zeros((t.count + 9, 5))
        for e, group in enumerate(t.groups):  # experiment e's values depend on a and b[e]
            G[group[1], [0, 1 + e]] = per_experiment_gradient(cut, t.x_unit, [group], d[[0, 1 + e]])
        G[t.count:, [0, 4]] = per_experiment_gradient(cut, new_x.repeat(9, 0), new_group, np.array([d[0], b]))
        with_nuisance.append(np.linalg.inv(12 * np.eye(5) + G.T @ np.linalg.solve(V, G))[0, 0])
        b_new_known.append(np.linalg.inv(12 * np.eye(4) + G[:, :4].T @ np.linalg.solve(V, G[:, :4]))[0, 0])
    assert trace[0] == pytest.approx(np.mean(with_nuisance), rel=1e-5)
    assert trace[0] > 1.01 * np.mean(b_new_known)


def test_the_posterior_criterion_with_theta_per_experiment_removes_the_variance_it_says(per_experiment_match):
    """References where calibration uses the emulator: experiment e's inputs at
    each draw's (a, b[e]). The first pick's gain equals the drop of the
    variance summed there (each component GP weighted as the criterion
    weights it) when every GP is refitted with that run added."""
    from stancal.designing.targets import run_table
    from stancal.designing.waves import fit_emulator

    match = per_experiment_match
    draws = match.nroy_frame().iloc[:300]  # NROY's columns: a, b[e1], b[e2], b[e3]; stands in for the posterior
    design = stancal.propose_runs(match, 2, criterion="posterior", posterior=draws, seed=3)
    assert list(design.next_runs.columns) == ["x", "a", "b"]
    assert (match.implausibility_at_runs(design.next_runs) <= 3.0).all()
    unit = match.box.theta_to_unit(draws.to_numpy())
    rng = np.random.default_rng(3)  # the references posterior_runs draws, in its order
    chosen_draws = unit[rng.choice(len(unit), 60, replace=False)]
    kept = rng.choice(3, 3, replace=False)
    t = match.targets
    references = np.vstack([np.column_stack([np.tile(t.groups[e][0], (60, 1)), chosen_draws[:, [0, 1 + e]]])
                            for e in kept])
    emulator = fit_emulator(match.data, *run_table(match.data, match.box), 3)
    run = match.box.to_unit(design.next_runs.iloc[:1])
    drop = 0.0
    for gp, weight in emulator.parts(t.groups):
        grown = GaussianProcess(gp.hyperparameters, np.vstack([gp.xt_runs, run]), np.append(gp.values, 0.3))
        drop += weight * (gp.predict(references)[1].sum() - grown.predict(references)[1].sum())
    assert design.notes["variance_reduction"][0] == pytest.approx(drop, rel=1e-3)


def test_a_fits_draws_become_nroys_columns_shared_then_each_experiments_own():
    """The posterior criterion's draws from a vector fit with per-experiment
    theta (the posterior as stancal.results.vector_result names it): NROY's
    order, a, then b[e1], b[e2], b[e3], draw by draw."""
    import xarray as xr

    from stancal.designing.loop import nroy_draws

    box = UnitBox.of(per_experiment_data(runs=12))
    chains, draws = 2, 3
    a = np.arange(chains * draws, dtype=float).reshape(chains, draws, 1)
    # stored experiment-theta-name last, as the fit's dims say; b[e] = 10 e + the draw's number
    b = (10 * np.arange(1, 4)[None, None, :] + a).reshape(chains, draws, 3, 1)
    posterior = xr.Dataset({"theta": (("chain", "draw", "theta_name"), a),
                            "theta_experiment": (("chain", "draw", "experiment", "experiment_theta_name"), b)},
                           coords={"theta_name": ["a"], "experiment": ["e1", "e2", "e3"],
                                   "experiment_theta_name": ["b"]})
    table = nroy_draws(posterior, box)
    expected = np.column_stack([np.arange(6.0), *(10 * e + np.arange(6.0) for e in (1, 2, 3))])
    np.testing.assert_array_equal(table, expected)


# ---- the posterior criterion's emulator -----------------------------------------------
def test_the_stage_one_emulator_on_the_design_box_is_the_calibrations():
    """Stage 1's hyperparameters live on the calibration's unit cube (the
    inputs over the physical and runs' range); on the design's box the GP
    must predict the same mean as stancal.fitting.stage_one's."""
    from stancal.fitting.stage_one import emulator_mean_function

    data = count_data("poisson")
    runs = data.runs.copy()
    runs.loc[2, "x"] = 1.4  # a run beyond the physical range: the two unit cubes differ
    runs.loc[2, "y"] = rate(runs.iloc[[2]])[0]
    data = data.with_runs(runs)
    hyper = {"emulator_mean": 0.1, "emulator_sd": 1.2, "emulator_length_scale": [0.4, 0.6, 0.5],
             "emulator_nugget": 0.02}
    box = UnitBox.of(data)
    emulator = calibration_emulator(data, box, {"hyperparameters": hyper})
    points = data.physical[["x"]]
    theta_unit = np.array([[0.3, 0.7], [0.6, 0.2]])
    theirs = emulator_mean_function(data, hyper, kernel_id=1)(points, theta_unit)
    ours = emulator.at(box.inputs_to_unit(points), theta_unit)[0]
    # the GPs differ by the jitter on the runs' diagonal alone (1e-6 sd^2 here, not there): 3e-5 at most;
    # the two cubes' widths differ by 40 %, so an unscaled length scale would be off by far more
    np.testing.assert_allclose(ours, theirs, rtol=1e-4)
    assert calibration_emulator(data, box, {}) is None


def test_the_posterior_criterion_uses_the_emulator_of_every_run_not_the_waves_refocused_one(toy_two_waves):
    # 30 runs proposed inside wave 1's NROY: the 10 per dimension of (x, a, b) that wave 2 needs to refocus
    loop = toy_two_waves
    match = loop.designs[-1].match
    assert match.waves[-1].runs_used < match.waves[-1].runs_total  # the wave's emulator is refocused
    draws = match.nroy_frame().iloc[:300]
    design = stancal.propose_runs(match, 1, criterion="posterior", posterior=draws, seed=3)
    assert design.notes["posterior_emulator"] == "fitted to every run, as stage 1"
    from stancal.designing.proposals import posterior_runs
    from stancal.designing.targets import run_table
    from stancal.designing.waves import fit_emulator

    xt, outputs = run_table(match.data, match.box)  # the runs of the last wave (loop.data holds its runs too)
    every = fit_emulator(match.data, xt, outputs, 3)
    unit = match.box.theta_to_unit(draws[["a", "b"]].to_numpy())
    _, gains = posterior_runs(every.parts(), unit, match.targets.x_unit, 1, seed=3)
    _, refocused = posterior_runs(match.cuts[-1].emulator.parts(), unit, match.targets.x_unit, 1, seed=3)
    assert design.notes["variance_reduction"][0] == pytest.approx(gains[0], rel=1e-9)
    assert refocused[0] != pytest.approx(gains[0], rel=1e-3)


# ---- the experiments criterion's discrepancy length -----------------------------------
def test_next_experiments_take_the_discrepancy_length_from_a_fit(toy_match):
    """A fit's posterior median length scale (original units), over the
    inputs' range, replaces the default 0.2; the criterion is then the
    direct computation's with that length."""
    import xarray as xr

    match = toy_match
    data = match.data
    default = stancal.propose_experiments(match, 1, seed=4)
    assert default.attrs["discrepancy_length"] == [0.2] and "no fit" in default.attrs["discrepancy_length_source"]
    draws = np.random.default_rng(1).lognormal(np.log(0.5), 0.2, size=(2, 50, 1))  # x's range is 1: 0.5 of it
    posterior = xr.Dataset({"delta_length_scale": (("chain", "draw", "delta_input"), draws)},
                           coords={"delta_input": ["x"]})

    class Fit:
        idata = {"posterior": posterior}

    settings = stancal.propose_experiments(match, 1, seed=4, fit=Fit())
    length = np.median(draws) / float(np.ptp(data.physical["x"]))
    assert settings.attrs["discrepancy_length"] == pytest.approx([length])
    assert settings.attrs["discrepancy_length_source"] == "the posterior median of the fit's"
    cut, rng = match.cuts[-1], np.random.default_rng(4)
    theta = match.nroy.theta_unit[rng.choice(len(match.nroy.theta_unit), 16, replace=False)]
    x = np.vstack([cut.targets.x_unit, settings[["x"]].to_numpy()])
    direct = direct_theta_trace(cut, theta, x, length)
    assert settings.attrs["theta_variance_trace"][0] == pytest.approx(direct, rel=1e-6)
    assert settings.attrs["theta_variance_trace"][0] != pytest.approx(default.attrs["theta_variance_trace"][0],
                                                                      rel=1e-3)


def test_next_experiments_leave_censored_rows_out_of_what_is_known():
    """The criterion equals the one on the observed rows alone."""
    from dataclasses import replace

    from stancal.designing.experiments import next_experiments

    data = censored_data()
    match = stancal.history_match(data, settings=DesignSettings(noise_sd=0.02, nroy_points=1000), seed=2)
    cut = match.cuts[-1]
    t, keep = cut.targets, cut.targets.observed
    observed = replace(t, x_unit=t.x_unit[keep], z=t.z[keep], noise_variance=t.noise_variance[keep],
                       lower=t.lower[keep], upper=t.upper[keep], model_variance=t.model_variance[keep])
    ours = stancal.propose_experiments(match, 2, seed=4)
    unit, theirs = next_experiments(Cut(cut.emulator, observed, cut.nth, cut.cutoff), match.nroy.theta_unit, 2, 4)
    assert ours.attrs["theta_variance_trace"] == pytest.approx(theirs, rel=1e-12)
