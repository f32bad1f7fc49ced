"""Vector outputs (issue: vector and functional outputs): the long-format
container and the runs' reduced basis (Higdon et al. 2008)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import assert_healthy, no_stancal_warnings

from stancal.problem.output_basis import DEFAULT_VARIANCE_SHARE, OutputBasis
from stancal.problem.validation import DataError
from stancal.problem.vector_data import VectorCalibrationData

THETA = {"k": (0.01, 0.1), "Ta": (15.0, 25.0)}
GRID = np.linspace(0, 60, 31)


def cooling(t, T0, k, Ta):
    return Ta + (T0 - Ta) * np.exp(-k * t)


def long_runs(count: int, seed: int, grid: np.ndarray = GRID) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    rows = []
    for r in range(count):
        T0, k, Ta = rng.uniform(55, 95), rng.uniform(*THETA["k"]), rng.uniform(*THETA["Ta"])
        rows.append(pd.DataFrame({"run": r, "T0": T0, "k": k, "Ta": Ta, "t": grid, "T": cooling(grid, T0, k, Ta)}))
    return pd.concat(rows, ignore_index=True)


def long_experiments(seed: int, experiments: int = 4) -> pd.DataFrame:
    """Ragged: each experiment at its own number of times, off the runs' grid."""
    rng = np.random.default_rng(seed)
    rows = []
    for e in range(experiments):
        t = np.sort(rng.uniform(0, 60, rng.integers(5, 15)))
        T0 = rng.uniform(60, 90)
        rows.append(pd.DataFrame({"exp": f"shot{e}", "T0": T0, "t": t, "sd": 0.3,
                                  "T": cooling(t, T0, 0.045, 21.3) + 0.3 * rng.standard_normal(t.size)}))
    return pd.concat(rows, ignore_index=True)


def vector_data(physical=None, runs=None, **kwargs) -> VectorCalibrationData:
    return VectorCalibrationData(long_experiments(1) if physical is None else physical, "exp", ["T0"], "T", "t",
                                 THETA, runs=long_runs(60, 2) if runs is None else runs, run="run",
                                 noise_sd="sd", **kwargs)


def test_basis_recovers_the_patterns_the_runs_are_made_of():
    rng = np.random.default_rng(0)
    patterns = np.stack([np.sin(np.pi * GRID / 60), np.cos(np.pi * GRID / 30), GRID / 60])
    outputs = 10 + rng.standard_normal((40, 3)) @ patterns
    basis = OutputBasis.from_runs(GRID, outputs, variance_share=0.999999)
    assert basis.count == 3 and basis.truncation_variance < 1e-20
    scores = basis.weights(outputs)
    np.testing.assert_allclose(scores.var(axis=0), 1, atol=0.05)  # Higdon's scaling: unit-variance weights
    np.testing.assert_allclose(basis.mean + basis.scale * scores @ basis.components.T, outputs, atol=1e-10)
    assert basis.explained.sum() == pytest.approx(1)


def test_cooling_curves_keep_what_the_share_asks_and_the_rest_is_the_truncation_error():
    data = vector_data()
    basis = data.basis
    assert data.run_outputs.shape == (60, 31)
    assert basis.explained.sum() >= DEFAULT_VARIANCE_SHARE and basis.explained[:-1].sum() < DEFAULT_VARIANCE_SHARE
    scores = basis.weights(data.run_outputs)
    left = (data.run_outputs - basis.mean) / basis.scale - scores @ basis.components.T
    assert np.mean(left**2) == pytest.approx(basis.truncation_variance, rel=1e-8)
    fewer = OutputBasis.from_runs(GRID, data.run_outputs, components=1)
    assert fewer.count == 1 and fewer.truncation_variance > basis.truncation_variance


def test_basis_at_ragged_indices_reproduces_a_curve_off_the_grid():
    """A new run's weights from its values on the grid, its curve at times
    between grid points: the basis gives the curve's piecewise-linear
    interpolant to within 3 rms truncation errors (the basis's own figure),
    and that interpolant lies within h^2 / 8 max|f''| = 0.075 degrees of the
    curve on a 2 s grid."""
    data = vector_data()
    basis = OutputBasis.from_runs(GRID, data.run_outputs, components=5)
    truncation = basis.scale * np.sqrt(basis.truncation_variance)
    t = np.random.default_rng(3).uniform(0, 60, 25)
    truth_on_grid, truth = cooling(GRID, 80, 0.05, 20), cooling(t, 80, 0.05, 20)
    mean, components = basis.at(t)
    predicted = mean + basis.scale * components @ basis.weights(truth_on_grid[None, :])[0]
    assert np.abs(predicted - np.interp(t, GRID, truth_on_grid)).max() < 3 * truncation
    assert np.abs(predicted - truth).max() < 0.075 + 3 * truncation
    with pytest.raises(DataError, match="outside the runs' grid"):
        basis.at(np.array([61.0]))


def test_the_interpolation_error_between_grid_values_is_estimated_from_the_runs():
    """The runs' own interpolation error (stancal.problem.output_basis.
    interpolation_variance), against the mean squared error of the linear
    interpolant at 2,000 uniform times off the 2 s grid: within 15 % (the
    curvature varies within an interval; a constant curvature gives it
    exactly); none for a field of four values; and the likelihood's
    independent error off the grid is the truncation's plus it."""
    data = vector_data()
    basis = data.basis
    t = np.random.default_rng(4).uniform(0, 60, 2000)
    settings = data.run_settings[["T0", "k", "Ta"]].to_numpy()
    on_grid = cooling(GRID[None, :], settings[:, :1], settings[:, 1:2], settings[:, 2:])
    off_grid = cooling(t[None, :], settings[:, :1], settings[:, 1:2], settings[:, 2:])
    interpolated = np.array([np.interp(t, GRID, run) for run in on_grid])
    empirical = np.mean(((interpolated - off_grid) / basis.scale) ** 2)
    assert basis.interpolation_variance == pytest.approx(empirical, rel=0.15)
    assert basis.independent_variance_at(np.array([t[0]])) == pytest.approx(
        basis.truncation_variance + basis.interpolation_variance, rel=1e-12)
    field = OutputBasis.from_runs(np.array([[0, 0], [0, 1], [1, 0], [1, 1.0]]),
                                  np.random.default_rng(0).standard_normal((6, 4)), components=2)
    assert field.interpolation_variance == 0


def test_a_fields_interpolation_error_on_a_tensor_grid_is_estimated_along_its_lines():
    """On a tensor grid of two index columns, the estimate (the 1-D one
    along each column's lines, summed) against the triangulation's mean
    squared error at 3,000 uniform points off the grid: measured 0.83 to
    0.91 of it on three grids of a smooth field, as the mixed derivative it
    leaves out adds a little; a scattered field gets none."""
    from scipy.interpolate import LinearNDInterpolator

    rng = np.random.default_rng(1)
    t, a = np.meshgrid(np.linspace(0, 3, 12), np.linspace(0, 2, 10), indexing="ij")
    grid = np.column_stack([t.ravel(), a.ravel()])
    p = rng.uniform([0.3, 0.5], [1.5, 2.0], (20, 2))

    def field(t, a):  # runs x points
        return np.exp(-p[:, :1] * t) * (1 + 0.5 * np.cos(a * p[:, 1:2])) + 0.2 * np.sin(2 * t + a)

    runs = field(grid[None, :, 0], grid[None, :, 1])
    basis = OutputBasis.from_runs(grid, runs, components=3)
    points = np.column_stack([rng.uniform(0, 3, 3000), rng.uniform(0, 2, 3000)])
    interpolated = np.array([LinearNDInterpolator(grid, run)(points) for run in runs])
    empirical = np.mean(((interpolated - field(points[None, :, 0], points[None, :, 1])) / basis.scale) ** 2)
    assert 0.75 * empirical <= basis.interpolation_variance <= empirical
    scattered = OutputBasis.from_runs(grid[:-1], runs[:, :-1], components=3)
    assert scattered.interpolation_variance == 0


def test_a_field_basis_interpolates_over_its_triangulation():
    u, v = np.meshgrid(np.linspace(0, 1, 6), np.linspace(0, 2, 5))
    grid = np.column_stack([u.ravel(), v.ravel()])
    rng = np.random.default_rng(1)
    outputs = rng.standard_normal((20, 2)) @ np.stack([grid[:, 0] + grid[:, 1], grid[:, 0] - 2 * grid[:, 1]])
    basis = OutputBasis.from_runs(grid, outputs, components=2)
    points = np.array([[0.33, 1.1], [0.9, 0.05]])
    mean, components = basis.at(points)
    fields = basis.mean + basis.scale * basis.weights(outputs) @ basis.components.T
    # the fields are linear in (u, v), so linear interpolation is exact
    exact = rng.standard_normal((1, 2))
    along = exact @ np.stack([points[:, 0] + points[:, 1], points[:, 0] - 2 * points[:, 1]])
    on_grid = exact @ np.stack([grid[:, 0] + grid[:, 1], grid[:, 0] - 2 * grid[:, 1]])
    np.testing.assert_allclose(mean + basis.scale * components @ basis.weights(on_grid)[0], along[0], atol=1e-10)
    np.testing.assert_allclose(fields, outputs, atol=1e-10)
    with pytest.raises(DataError, match="convex hull"):
        basis.at(np.array([[1.5, 1.0]]))


def test_experiments_are_one_row_each_with_their_inputs():
    data = vector_data()
    assert list(data.experiments.index) == ["shot0", "shot1", "shot2", "shot3"]
    assert list(data.experiments.columns) == ["T0"]
    assert len(data.run_settings) == 60


def test_an_experiment_whose_inputs_vary_is_named():
    physical = long_experiments(1)
    physical.loc[physical.index[physical.exp == "shot2"][1], "T0"] += 1
    with pytest.raises(DataError, match="column 'T0' varies within experiment 'shot2'"):
        vector_data(physical)


def test_runs_on_different_grids_are_named():
    runs = long_runs(60, 2)
    runs = runs[~((runs.run == 7) & (runs.t == 30.0))]
    with pytest.raises(DataError, match="run '7' is on a grid of 30 output indices"):
        vector_data(runs=runs)
    shifted = long_runs(60, 2)
    shifted.loc[shifted.run == 3, "t"] += 0.5
    with pytest.raises(DataError, match="run '3'"):
        vector_data(runs=shifted)


def test_indices_outside_the_runs_range_name_the_experiment():
    physical = long_experiments(1)
    physical.loc[physical.index[physical.exp == "shot1"][-1], "t"] = 75.0
    with pytest.raises(DataError, match=r"output index 't' lies outside the runs' range \[0, 60\].*shot1"):
        vector_data(physical)


def test_fewer_runs_than_components_is_an_error():
    # 4 runs span less of T0 than the experiments: the range warning comes before the error
    with pytest.raises(DataError, match="4 runs for 3 output components"), \
            no_stancal_warnings(allow="outside the simulator runs' range"):
        vector_data(runs=long_runs(4, 2), variance_share=0.99999999)
    with pytest.raises(DataError, match="more runs than components"):
        vector_data(runs=long_runs(60, 2), components=60)


def test_a_run_whose_theta_varies_within_it_is_named():
    runs = long_runs(60, 2)
    runs.loc[runs.index[runs.run == 5][3], "k"] = 0.02
    with pytest.raises(DataError, match="column 'k' varies within run '5'"):
        vector_data(runs=runs)


def test_known_noise_must_be_positive_and_names_the_rows():
    physical = long_experiments(1)
    physical.loc[4, "sd"] = 0.0
    with pytest.raises(DataError, match=r"column 'sd' \(known noise sd\) must be positive; rows \[4\]"):
        vector_data(physical)


def test_per_experiment_theta_may_not_clash_with_shared_theta():
    with pytest.raises(DataError, match=r"\['k'\] clash"):
        vector_data(theta_per_experiment={"k": (0.0, 1.0)})
    runs = long_runs(60, 2).assign(velocity=1.5)
    data = vector_data(runs=runs, theta_per_experiment={"velocity": (1.0, 2.0)})
    assert [p.name for p in data.all_parameters] == ["k", "Ta", "velocity"]


def test_component_emulator_predicts_held_out_curves_within_its_bands():
    """Stage 1 on 60 runs of the cooling curve, checked on 40 runs it never
    saw, at times off the grid: the rms error under 2 % of the runs' sd
    (measured 0.3 % with the 4 components the default keeps), and the truth
    inside the 90 % band at 80 to 99.5 % of the held-out values (measured
    90.6 %, the interpolation error between grid times included: the bands
    are neither too narrow nor useless; 77 % without it)."""
    from stancal.fitting.stage_one import fit_vector_emulator

    data = vector_data()
    emulator = fit_vector_emulator(data, seed=1)
    held_out = long_runs(40, 9).groupby("run").first()[["T0", "k", "Ta"]]
    t = np.linspace(0.5, 59.5, 17)
    mean, variance = emulator.predict(data.scaling.to_unit(held_out, ["T0", "k", "Ta"]), t)
    held_out = held_out.to_numpy()
    truth = cooling(t[None, :], held_out[:, :1], held_out[:, 1:2], held_out[:, 2:3])
    z = (truth - mean) / np.sqrt(variance)
    assert np.sqrt(np.mean((truth - mean) ** 2)) < 0.02 * data.run_outputs.std()
    assert 0.80 <= np.mean(np.abs(z) < 1.645) <= 0.995


# ---- modular_vector.stan against a quadrature of the same posterior ---------

def moments_reference(stan_data: dict, emulator, theta_unit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """modular_vector.stan's mean and covariance of the standardised values
    (no discrepancy, known noise) at one shared theta, in numpy."""
    points = np.column_stack([np.asarray(stan_data["x"]), np.tile(theta_unit, (stan_data["E"], 1))])
    experiment = np.asarray(stan_data["experiment"]) - 1
    components = np.asarray(stan_data["components"])
    mu, K = np.zeros(stan_data["N"]), np.diag(np.asarray(stan_data["known_noise_sd"]) ** 2
                                              + stan_data["truncation_variance"])
    for c, gp in enumerate(emulator.components):
        mean, cov = gp.predict(emulator.xt_runs, emulator.variance_runs, points)
        mu += components[:, c] * mean[experiment]
        K += components[:, c, None] * cov[np.ix_(experiment, experiment)] * components[None, :, c]
    K[np.diag_indices_from(K)] += 1e-6 * max(gp.prior_variance for gp in emulator.components)  # add_jitter's
    return mu, K


def log_density_reference(stan_data: dict, emulator, theta_unit: np.ndarray) -> float:
    """modular_vector.stan's log likelihood (no discrepancy, known noise) at
    one shared theta, in numpy: the reference the sampler is checked against."""
    mu, K = moments_reference(stan_data, emulator, theta_unit)
    L = np.linalg.cholesky(K)
    z = np.linalg.solve(L, np.asarray(stan_data["y"]) - mu)
    return float(-0.5 * z @ z - np.log(np.diag(L)).sum())


def _grid_moments(stan_data, emulator, centre, half_width, points=61):
    axes = [np.clip(np.linspace(c - h, c + h, points), 0, 1) for c, h in zip(centre, half_width, strict=False)]
    grid = np.array(np.meshgrid(*axes, indexing="ij")).reshape(2, -1).T
    log_p = np.array([log_density_reference(stan_data, emulator, theta) for theta in grid])
    weight = np.exp(log_p - log_p.max())
    weight /= weight.sum()
    mean = weight @ grid
    return grid[np.argmax(log_p)], mean, np.sqrt(weight @ (grid - mean) ** 2)


@pytest.fixture(scope="session")
def vector_problem():
    return vector_data(runs=long_runs(40, 2))


@pytest.fixture(scope="session")
def vector_stage_one(vector_problem):
    """Stage 1 of vector_problem at seed 3 (the fits' below)."""
    from stancal.fitting.stage_one import fit_vector_emulator

    return fit_vector_emulator(vector_problem, seed=3)


@pytest.fixture(scope="session")
def vector_reference(vector_problem, vector_stage_one):
    """The modular density of vector_problem with stage 1 at seed 3 (the
    fits' below), and theta's posterior mean and sd on the unit box by grid
    quadrature in numpy: a coarse grid over the box, then finer ones about
    the mode."""
    from stancal.fitting.vector_calibrate import prediction_rows
    from stancal.problem.options import VectorOptions
    from stancal.stan.vector_standata import modular_vector_data

    emulator = vector_stage_one
    stan_data = modular_vector_data(vector_problem, VectorOptions("none", "known"), emulator,
                                    prediction_rows(vector_problem))
    best, _, _ = _grid_moments(stan_data, emulator, [0.5, 0.5], [0.5, 0.5], points=41)
    _, mean, sd = _grid_moments(stan_data, emulator, best, [0.05, 0.05], points=41)
    _, mean, sd = _grid_moments(stan_data, emulator, mean, 6 * sd)
    return emulator, mean, sd


def test_modular_vector_posterior_matches_quadrature(vector_problem, vector_reference):
    """Ragged experiments, known noise, no discrepancy: theta's posterior
    mean within 0.15 sd and its sd within 10 % of a grid quadrature of the
    same density, computed in numpy (coarse grid over the box, then finer
    ones about the mode); R-hat <= 1.01."""
    from stancal.fitting.vector_calibrate import calibrate_vector

    data = vector_problem
    # chains spread over the box left one of the four in a second theta mode of weight 0.000 at this seed;
    # started in the modes found before sampling, all four share the main one, and the far optima are reported
    # 4 x (500 + 500): the bulk ESS of theta (about 1,000 or more) puts the Monte Carlo error of its mean near
    # 0.03 sd and of its sd near 2 %, well inside the 0.15 sd and 10 % below
    with no_stancal_warnings():
        result = calibrate_vector(data, discrepancy="none", chains=4, warmup=500, draws=500, seed=3)
    assert_healthy(result)
    assert len(result.modes) <= 1, result.modes
    reported = result.to_summary_json()["start_modes"]
    assert reported[0]["chains"] == [0, 1, 2, 3] and any(not m["chains"] for m in reported[1:]), reported
    emulator, mean, sd = vector_reference  # stage 1 at the fit's seed: the emulator fixed in the fit
    np.testing.assert_array_equal(result.emulator.components[0].alpha, emulator.components[0].alpha)
    summary = result.theta_summary()
    print({p.name: (summary[p.name]["mean"], summary[p.name]["sd"], p.lower + (p.upper - p.lower) * mean[q],
                    (p.upper - p.lower) * sd[q]) for q, p in enumerate(data.parameters)}, result.modes)
    for q, p in enumerate(data.parameters):
        width = p.upper - p.lower
        reference_mean, reference_sd = p.lower + width * mean[q], width * sd[q]
        assert abs(summary[p.name]["mean"] - reference_mean) <= 0.15 * reference_sd, (p.name, summary, mean, sd)
        assert abs(summary[p.name]["sd"] / reference_sd - 1) <= 0.10, (p.name, summary, mean, sd)


@pytest.mark.slow
def test_modular_vector_recovers_shared_and_per_experiment_theta_beside_a_discrepancy():
    """Five cool-downs, each read at its own times by a probe with its own
    offset (a per-experiment theta), the room warming the probe by a
    smooth gap the simulator lacks; noise sd estimated per experiment. The
    90 % intervals cover k, Ta and every offset, the sampler is healthy,
    and the predictions are curves per experiment along the output index
    whose zeta band holds the readings."""
    from stancal.fitting.vector_calibrate import calibrate_vector

    rng = np.random.default_rng(11)
    offsets = rng.uniform(-0.8, 0.8, 5)
    rows = []
    for e, offset in enumerate(offsets):
        t = np.sort(rng.uniform(0, 60, rng.integers(8, 14)))
        T0 = rng.uniform(60, 90)
        gap = 0.6 * np.sin(np.pi * t / 60)
        rows.append(pd.DataFrame({"exp": f"cool{e}", "T0": T0, "t": t, "T": cooling(t, T0, 0.045, 21.3) + offset
                                  + gap + 0.2 * rng.standard_normal(t.size)}))
    physical = pd.concat(rows, ignore_index=True)
    runs = long_runs(50, 4)
    runs["offset"] = np.repeat(rng.uniform(-1, 1, 50), len(GRID))
    runs["T"] += runs["offset"]
    data = VectorCalibrationData(physical, "exp", ["T0"], "T", "t", THETA, theta_per_experiment={"offset": (-1, 1)},
                                 runs=runs, run="run")
    result = calibrate_vector(data, discrepancy="gp", noise="per_experiment", chains=4, warmup=500, draws=500,
                              seed=2, adapt_delta=0.95)
    # a GP discrepancy beside per-experiment noise: the bar this test had before (2 of 2,000), not re-measured
    assert_healthy(result, divergences=2)
    summary = result.theta_summary()
    for name, truth in (("k", 0.045), ("Ta", 21.3)):
        assert summary[name]["q05"] <= truth <= summary[name]["q95"], (name, summary[name])
    offset_draws = np.asarray(result.idata["posterior"]["theta_experiment"]).reshape(-1, 5)
    low, high = np.quantile(offset_draws, [0.05, 0.95], axis=0)
    assert np.all((low <= offsets) & (offsets <= high)), (low, offsets, high)
    zeta = result.idata["predictions"]["zeta"]
    assert zeta.dims[2:] == ("experiment", "output_point") and "t" in zeta.coords
    band = np.quantile(np.asarray(zeta).reshape(-1, *zeta.shape[2:]), [0.025, 0.975], axis=0)
    held = 0
    for e, name in enumerate(data.experiments.index):
        readings = physical[physical.exp == name]
        lower = np.interp(readings.t, zeta["t"], band[0, e]) - 3 * 0.2
        upper = np.interp(readings.t, zeta["t"], band[1, e]) + 3 * 0.2
        held += int(((readings["T"] >= lower) & (readings["T"] <= upper)).sum())
    assert held >= 0.95 * len(physical)


def test_many_runs_condition_the_weights_covariance_on_a_subset_that_only_widens_it():
    """Above VARIANCE_RUNS runs the weights' covariance conditions on a
    random subset (subset of data): the means are unchanged (all runs), and
    the variances are never smaller than given all runs, nor more than the
    prior's."""
    from scipy import linalg

    from stancal.fitting.stage_one import fit_vector_emulator
    from stancal.numerics.scalable_emulator import run_covariance, se_correlation
    from stancal.numerics.vector_emulator import VectorEmulator

    data = vector_data(runs=long_runs(300, 5))
    full = fit_vector_emulator(data, seed=1)
    xt = full.xt_runs
    subset = VectorEmulator.fit(data.basis, xt, data.run_outputs, seed=1, variance_runs=60)
    assert len(subset.variance_runs) == 60 and len(full.variance_runs) == 300
    points = np.random.default_rng(2).uniform(size=(25, xt.shape[1]))
    for exact, approximate in zip(full.components, subset.components, strict=False):
        h = exact.hyperparameters
        cross = h.sd**2 * se_correlation(points, xt, h.length_scale)
        factor = linalg.cho_factor(run_covariance(xt, h), lower=True)
        exact_variance = h.sd**2 - np.einsum("ij,ji->i", cross, linalg.cho_solve(factor, cross.T))
        mean, covariance = approximate.predict(xt, subset.variance_runs, points)
        assert np.allclose(mean, exact.predict(xt, full.variance_runs, points)[0])
        variance = np.diag(covariance)
        assert (variance >= exact_variance - 1e-9 * h.sd**2).all() and (variance <= h.sd**2 + 1e-12).all()
        assert variance.mean() > exact_variance.mean()  # the subset does cost certainty


def test_the_posterior_keeps_one_noise_sd_or_one_per_experiment():
    """noise = 'one' is a scalar per draw; 'per_experiment' has the
    experiment dimension, even with a single experiment."""
    from stancal.problem.options import VectorOptions
    from stancal.results.vector_result import vector_datatree

    data = vector_data(physical=long_experiments(1, experiments=1))
    rows = pd.DataFrame({"exp": "shot0", "t": [1.0, 2.0]})
    chains, draws = 2, 3
    base = {"theta": np.zeros((chains, draws, 2)), "delta_length_scale": np.ones((chains, draws, 2)),
            "delta_sd_original": np.ones((chains, draws, 1)), "y_rep": np.zeros((chains, draws, len(data.physical))),
            **{f"{k}_new": np.zeros((chains, draws, 2)) for k in ("f", "delta", "zeta")}}
    for noise, dims in (("one", ("chain", "draw")), ("per_experiment", ("chain", "draw", "experiment"))):
        tree = vector_datatree({**base, "noise_sd_original": np.ones((chains, draws, 1))}, {}, data, rows, [],
                               VectorOptions("gp", noise), None, samples_emulator=False, from_runs=True)
        assert tree["posterior"]["noise_sd"].dims == dims


@pytest.mark.slow
def test_joint_vector_emulator_agrees_with_the_quadrature_when_the_runs_pin_it_down(vector_problem,
                                                                                     vector_reference):
    """koh_emulator for a vector output samples the weight GPs'
    hyperparameters with theta. With 40 runs of a smooth simulator the
    emulator is nearly exact, so theta's posterior must agree with the
    quadrature of the modular density (stage 1 fixed): means within 0.25 sd,
    sds within 20 %; R-hat <= 1.01, and the hyperparameters are in the
    posterior."""
    from stancal.fitting.vector_calibrate import calibrate_vector

    # The default basis (4 components). Its chains start at the modular density's mode (joint_start): spread
    # over the theta box, as before issue 31, two of four stayed in modes of weight 0.000 where the data bend
    # the weight GPs (R-hat 1.035 there, at this seed and 4 x (500 + 500)); the main mode's chains mixed
    # (R-hat <= 1.007). Now one mode, R-hat <= 1.006, theta's sds 5 % wider than the quadrature's. Slow: the
    # joint fit factors every component's runs covariance at each step, 290 s on two shared cores
    data = vector_problem
    with no_stancal_warnings():
        result = calibrate_vector(data, method="koh_emulator", discrepancy="none", chains=4, warmup=500,
                                  draws=500, seed=3)
    assert result.method == "koh_emulator_vector"
    assert_healthy(result)
    assert result.idata["posterior"]["weight_gp_length_scale"].dims[2:] == ("component", "emulator_input")
    _, mean, sd = vector_reference  # stage 1 at the fit's seed, where the joint fit started
    summary = result.theta_summary()
    for q, p in enumerate(data.parameters):
        width = p.upper - p.lower
        reference_mean, reference_sd = p.lower + width * mean[q], width * sd[q]
        print(p.name, summary[p.name]["mean"], summary[p.name]["sd"], reference_mean, reference_sd)
        assert abs(summary[p.name]["mean"] - reference_mean) <= 0.25 * reference_sd, (p.name, summary[p.name])
        assert abs(summary[p.name]["sd"] / reference_sd - 1) <= 0.20, (p.name, summary[p.name])


def test_the_joint_vector_fit_starts_at_the_modular_mode(vector_problem, vector_reference):
    """koh_emulator's chains start theta at the mode of the modular density
    (joint_start: the same program, the weight GPs at stage 1), found by
    L-BFGS: within 0.5 sd of the quadrature's posterior mean of that density
    (its mode and mean differ by less than that: the posterior is near
    normal at 40 runs). Chains spread over the box fell into modes of the
    joint posterior where the data bend the emulator (docs/vector.md)."""
    from stancal.fitting.plan import plan_vector
    from stancal.fitting.vector_calibrate import joint_start, prediction_rows
    from stancal.problem.options import VectorOptions
    from stancal.stan.backends import get_backend
    from stancal.stan.vector_standata import build_vector_stan_data

    data, options = vector_problem, VectorOptions("none", "known")
    plan = plan_vector(data, None, "koh_emulator", options)
    emulator, mean, sd = vector_reference
    stan_data = build_vector_stan_data(data, plan.program.data, options, prediction_rows(data), emulator)
    assert stan_data["joint"] == 1
    start = joint_start(get_backend(None), plan.main_program(), stan_data, seed=3)
    assert np.all(np.abs(np.asarray(start["theta_unit"]) - mean) <= 0.5 * sd), (start, mean, sd)


def test_modular_vector_chains_start_in_the_main_mode_and_the_far_ones_are_reported(vector_problem,
                                                                                     vector_reference):
    """modular's chains start theta in the modes of its own density found by
    L-BFGS before sampling (stancal.fitting.inits.mode_inits): here every
    run from a spread start but those that ended far below reached one mode
    within 0.5 sd of the quadrature's posterior mean (mode and mean differ
    by less: the posterior is near normal at 40 runs), and the chains start
    at those runs' spread starts, apart; theta spread over the box alone
    started one chain at (0.12, 0.62), from which the sampler stayed in a
    second mode of weight 0.000; the optima far below the best (on a bound
    of the box here) get no chain and are reported."""
    from stancal.fitting.inits import MINOR_OPTIMUM_GAP, START_OPTIMA, spread_theta_inits
    from stancal.fitting.plan import plan_vector
    from stancal.fitting.vector_calibrate import chain_inits, prediction_rows
    from stancal.problem.options import VectorOptions
    from stancal.stan.backends import get_backend
    from stancal.stan.vector_standata import build_vector_stan_data

    data, options = vector_problem, VectorOptions("none", "known")
    plan = plan_vector(data, None, "modular", options)
    emulator, mean, sd = vector_reference
    stan_data = build_vector_stan_data(data, plan.program.data, options, prediction_rows(data), emulator)
    spread = np.array([i["theta_unit"] for i in spread_theta_inits(4, 2, np.random.default_rng(3))])
    assert np.any(np.abs(spread - mean) > 0.5 * sd)  # the check below is not one spread starts pass
    inits, modes = chain_inits(plan.program, get_backend(None), plan.main_program(), stan_data, emulator, 4, seed=3)
    assert np.all(np.abs(np.array(modes[0].theta_unit) - mean) <= 0.5 * sd), (modes[0], mean, sd)
    assert modes[0].chains == (0, 1, 2, 3) and modes[0].below_best == 0
    starts = {tuple(i["theta_unit"]) for i in spread_theta_inits(START_OPTIMA, 2, np.random.default_rng(3))}
    theta = [tuple(i["theta_unit"]) for i in inits]
    assert set(theta) <= starts and len(set(theta)) == min(4, modes[0].starts)  # the main mode's runs' starts: apart
    far = [m for m in modes if not m.chains]
    assert far and all(m.below_best > MINOR_OPTIMUM_GAP for m in far), modes


def test_the_joint_vector_density_at_stage_ones_hyperparameters_is_the_quadratures(vector_problem,
                                                                                     vector_stage_one):
    """koh_emulator_vector (Higdon et al. 2008: the weight GPs'
    hyperparameters sampled with theta, the runs' weights in the
    likelihood) with its hyperparameters held at stage 1's: its log density
    over theta is the numpy density the modular quadrature integrates
    (log_density_reference), up to a constant, to 1e-8 at seven theta, so
    the joint posterior given those hyperparameters is that quadrature's.
    The runs' marginal likelihood and the hyperparameters' priors are the
    constant; the weights at the experiments condition on every run. A
    default-run check of the joint program against the reference; the slow
    test above samples it."""
    from stancal.fitting.plan import plan_vector
    from stancal.fitting.vector_calibrate import prediction_rows
    from stancal.problem.options import VectorOptions
    from stancal.stan.backends import get_backend
    from stancal.stan.standata import to_stan_json
    from stancal.stan.vector_standata import build_vector_stan_data

    data, emulator = vector_problem, vector_stage_one  # vector_reference's stage 1, without its quadrature
    assert len(emulator.variance_runs) == len(emulator.xt_runs)  # the reference conditions on every run too
    plan = plan_vector(data, None, "koh_emulator", VectorOptions("none", "known"))
    stan_data = build_vector_stan_data(data, plan.program.data, plan.options, prediction_rows(data), emulator)
    assert stan_data["joint"] == 1
    unconstrain, log_density = get_backend().log_density_functions(plan.main_program(), to_stan_json(stan_data))
    hyper = [gp.hyperparameters for gp in emulator.components]
    theta = np.random.default_rng(5).uniform(0.05, 0.95, size=(7, 2))
    at_stage_one = {"theta_unit": theta[None], "theta_exp_unit": np.zeros((1, 7, 0)),
                    "weight_gp_mean_free": np.tile([h.mean for h in hyper], (1, 7, 1)),
                    "weight_gp_sd_free": np.tile([h.sd for h in hyper], (1, 7, 1)),
                    "weight_gp_length_scale_free": np.tile([h.length_scale for h in hyper], (1, 7, 1, 1)),
                    "weight_gp_nugget_free": np.tile([h.nugget for h in hyper], (1, 7, 1))}
    stan = log_density(unconstrain(at_stage_one)[0]) - np.log(theta * (1 - theta)).sum(axis=1)  # no Jacobian
    reference = np.array([log_density_reference(stan_data, emulator, t) for t in theta])
    assert np.ptp(reference) > 10  # theta matters: the check is not between flat densities
    np.testing.assert_allclose(np.diff(stan), np.diff(reference), rtol=1e-8, atol=1e-8)
