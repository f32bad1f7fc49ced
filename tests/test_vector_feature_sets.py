"""A vector output that is a set of features, not a curve, and the weight
GPs' nugget at the experiments (issue 31, SEPIA's Al-5083 flyer plates;
Walters et al. 2018, J. Appl. Phys. 124; Higdon et al. 2008, JASA 103).

- Each value measured at a grid index has no interpolation error: the
  mean and the components there are the runs' own. An error estimated
  between neighbouring features (V10 of one shot beside V4 of the next)
  made Al-5083's likelihood add 42 m/s of independent error to values
  measured to 1.5-2.2 m/s.
- The weights' predictive covariance keeps each GP's nugget, one jitter per
  distinct emulator input (Higdon et al. 2008; SEPIA's 1/lamWs): without
  it the emulator is surest at its runs, where its error is the nugget's,
  and chains without a discrepancy settled in the theta box's corners,
  where its variance is large enough to excuse any data.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ROOT
from scipy import optimize
from test_vector_outputs import log_density_reference, long_experiments, long_runs

from stancal.problem.output_basis import OutputBasis
from stancal.problem.vector_data import VectorCalibrationData

FEATURES = np.arange(1.0, 13.0)


def feature_runs(count: int, seed: int) -> np.ndarray:
    """(count, 12): three shots' four features, each shot at its own level
    (so neighbouring features across shots jump), driven by two parameters."""
    rng = np.random.default_rng(seed)
    a, b = rng.uniform(size=(2, count, 1))
    level = np.repeat([200.0, 350.0, 480.0], 4)[None, :]
    return level * (1 + 0.1 * a) + 5 * b * np.tile(np.arange(4), 3)[None, :]


def test_a_value_on_the_grid_carries_no_interpolation_error():
    """The truncation error everywhere; the interpolation error (large here,
    the features jump between shots) only where a value lies off the grid."""
    basis = OutputBasis.from_runs(FEATURES[:, None], feature_runs(50, 1), components=1)
    assert basis.interpolation_variance > 10 * basis.truncation_variance  # measured 0.58 against 0.028
    on, off = basis.independent_variance_at(FEATURES), basis.independent_variance_at(np.array([1.5, 7.25]))
    np.testing.assert_allclose(on, basis.truncation_variance, rtol=1e-12)
    np.testing.assert_allclose(off, basis.truncation_variance + basis.interpolation_variance, rtol=1e-12)
    _, variance = basis.predict(np.array([4.0, 4.5]), np.zeros((1, 1)), np.zeros((1, 1)))
    np.testing.assert_allclose(variance[0] / basis.scale**2,
                               basis.truncation_variance + np.array([0, basis.interpolation_variance]), rtol=1e-10)


def no_input_data(count: int = 40) -> VectorCalibrationData:
    """Cool-downs with no inputs, T0 a shared theta: every experiment at one
    emulator point (as Al-5083's shots), measured at grid times."""
    physical = long_experiments(1, experiments=3)
    physical["t"] = np.round(physical["t"] / 2) * 2  # onto the runs' grid (every 2 s)
    physical = physical.drop_duplicates(["exp", "t"]).drop(columns="T0")
    return VectorCalibrationData(physical, "exp", [], "T", "t", {"k": (0.01, 0.1), "Ta": (15.0, 25.0),
                                                                "T0": (55.0, 95.0)},
                                 runs=long_runs(count, 2), run="run", noise_sd="sd")


@pytest.fixture(scope="module")
def emulated():
    from stancal.fitting.stage_one import fit_vector_emulator

    data = no_input_data()
    return data, fit_vector_emulator(data, seed=1)


def test_the_weights_keep_the_nugget_at_the_experiments(emulated):
    """The weights' predictive covariance at three points (a run's own point
    twice, another point): the smooth GP's, given the variance runs, plus
    the nugget's variance wherever two points are one (a run's own point
    and itself: one jitter), nowhere else."""
    from scipy import linalg

    from stancal.numerics.scalable_emulator import run_covariance, se_correlation

    _, emulator = emulated
    run = emulator.xt_runs[emulator.variance_runs[0]]
    points = np.vstack([run, run, np.clip(run + 0.2, 0, 1)])
    chosen = emulator.xt_runs[emulator.variance_runs]
    for gp in emulator.components:
        h = gp.hyperparameters
        cross = h.sd**2 * se_correlation(points, chosen, h.length_scale)
        smooth = (h.sd**2 * se_correlation(points, points, h.length_scale)
                  - cross @ linalg.solve(run_covariance(chosen, h), cross.T))
        same = np.array([[1, 1, 0], [1, 1, 0], [0, 0, 1.0]])
        _, cov = gp.predict(emulator.xt_runs, emulator.variance_runs, points)
        np.testing.assert_allclose(cov, smooth + h.nugget**2 * same, rtol=1e-6, atol=1e-9 * h.sd**2)
        assert cov[0, 0] >= h.nugget**2  # the emulator is never surer than the runs' jitter


def test_experiments_share_a_jitter_only_at_one_emulator_point():
    from stancal.stan.vector_standata import same_emulator_point

    np.testing.assert_array_equal(same_emulator_point(np.zeros((3, 0)), 0), np.ones((3, 3)))
    x = np.array([[0.1, 0.5], [0.1, 0.5], [0.2, 0.5]])
    np.testing.assert_array_equal(same_emulator_point(x, 0), [[1, 1, 0], [1, 1, 0], [0, 0, 1]])
    np.testing.assert_array_equal(same_emulator_point(x, 1), np.eye(3))  # each its own theta_e


def test_modular_vector_stan_density_is_the_numpy_one_with_no_inputs(emulated):
    """modular_vector.stan's log density at several theta, against the numpy
    reference (log_density_reference: per-value independent error, the nugget shared
    by experiments at one point), up to a constant, to 1e-8: the program
    and the Python emulator are one model."""
    from stancal.fitting.plan import plan_vector
    from stancal.fitting.vector_calibrate import prediction_rows
    from stancal.problem.options import VectorOptions
    from stancal.stan.backends import get_backend
    from stancal.stan.standata import to_stan_json
    from stancal.stan.vector_standata import build_vector_stan_data

    data, emulator = emulated
    plan = plan_vector(data, None, "modular", VectorOptions("none", "known"))
    stan_data = build_vector_stan_data(data, plan.program.data, plan.options, prediction_rows(data), emulator)
    assert np.allclose(stan_data["truncation_variance"], data.basis.truncation_variance)  # all on the grid
    assert np.array_equal(stan_data["same_point"], np.ones((3, 3)))
    _, log_density = get_backend().log_density_functions(plan.main_program(), to_stan_json(stan_data))
    theta = np.random.default_rng(4).uniform(0.05, 0.95, size=(5, 3))
    stan = log_density(np.log(theta / (1 - theta))) - np.log(theta * (1 - theta)).sum(axis=1)  # no Jacobian
    reference = np.array([log_density_reference(stan_data, emulator, t) for t in theta])
    np.testing.assert_allclose(np.diff(stan), np.diff(reference), rtol=1e-8, atol=1e-8)


def optima(log_density, dimension: int, starts: int, seed: int) -> np.ndarray:
    """L-BFGS-B from random starts in the unit box: the optima's log densities
    and how many of their coordinates sit on a bound."""
    rng = np.random.default_rng(seed)
    found = []
    for _ in range(starts):
        best = optimize.minimize(lambda u: -log_density(u), rng.uniform(0.03, 0.97, dimension),
                                 method="L-BFGS-B", bounds=[(0, 1)] * dimension)
        found.append((-best.fun, int(np.sum((best.x < 1e-3) | (best.x > 1 - 1e-3)))))
    return np.array(found)


@pytest.mark.slow
def test_al5083s_modular_density_has_no_optimum_in_the_boxs_corners():
    """SEPIA's Al-5083 (1,000 runs, 11 theta, no discrepancy): 12 L-BFGS
    runs on the modular density from random starts. Without the nugget
    (measured before the fix, values on the grid) three of twelve stopped with 6, 9 and 11 of
    the 11 coordinates on a bound, 14 to 24 below the best optimum; with it,
    every optimum has at most 2 coordinates on a bound and lies within 5 of
    the best (measured: at most 1, within 2.2)."""

    from stancal.fitting.stage_one import fit_vector_emulator
    from stancal.fitting.vector_calibrate import prediction_rows
    from stancal.problem.config import load_config
    from stancal.problem.options import VectorOptions
    from stancal.stan.vector_standata import modular_vector_data

    data = load_config(ROOT / "case_studies" / "al5083" / "config.toml").data
    emulator = fit_vector_emulator(data, seed=1)
    stan_data = modular_vector_data(data, VectorOptions("none", "known"), emulator, prediction_rows(data))
    found = optima(lambda u: log_density_reference(stan_data, emulator, u), 11, starts=12, seed=0)
    assert found[:, 1].max() <= 2, found
    assert found[:, 0].max() - found[:, 0].min() <= 5, found


def test_a_feature_set_config_keeps_every_value_on_the_grid():
    """Al-5083's values all sit at features 1-12, the runs' grid: no
    interpolation error reaches its likelihood."""

    from stancal.problem.config import load_config

    data = load_config(ROOT / "case_studies" / "al5083" / "config.toml").data
    variance = data.basis.independent_variance_at(data.physical[data.output_index].to_numpy())
    assert data.basis.interpolation_variance > 1  # between features: meaningless, and large
    np.testing.assert_allclose(variance, data.basis.truncation_variance)


def test_stage_one_fits_the_weight_gps_on_one_blas_thread(monkeypatch):
    """Stage 1's weight GPs run on one BLAS thread whatever the caller's
    setting: thousands of small factorisations gain nothing from threads,
    and OpenBLAS's threads spin-wait on busy cores (Al-5083's 100-run stage 1
    on 2 shared cores: 78 s with 2 threads, 2.7 s with one)."""
    from types import SimpleNamespace

    from threadpoolctl import threadpool_info, threadpool_limits

    from stancal.fitting import stage_one
    from stancal.problem.config import load_config

    seen = []

    def blas_threads():
        return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]

    def fit(basis, xt, outputs, seed):
        seen.extend(blas_threads())
        return SimpleNamespace(hyperparameter_runs=len(xt))

    monkeypatch.setattr(stage_one.VectorEmulator, "fit", staticmethod(fit))
    data = load_config(ROOT / "case_studies" / "al5083" / "config_subset.toml").data
    with threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        if not before or set(before) != {2}:  # a BLAS built single-threaded, or none found: nothing to restrict
            pytest.skip(f"the BLAS pools report {before} threads under a limit of 2, not 2")
        stage_one.fit_vector_emulator(data, seed=1)
        after = blas_threads()
    assert seen and set(seen) == {1}
    assert set(after) == {2}, f"the BLAS pools report {after} threads after stage 1, not the caller's 2"
