"""Each wave's emulator is checked before it cuts (Bastos & O'Hagan 2009):
its held-out standardised errors, and the variance inflation they ask for
(stancal.designing.emulator_checks). No Stan."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import qmc

from stancal.designing.emulator_checks import Check, check, checked, k_fold, leave_one_out
from stancal.designing.emulators import GaussianProcess, ScalarEmulator, emulator_from_dict
from stancal.designing.implausibility import Cut
from stancal.designing.targets import Targets
from stancal.designing.waves import Wave
from stancal.numerics.scalable_emulator import JITTER, Hyperparameters


def smooth_runs(count: int = 24, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    xt = qmc.LatinHypercube(d=2, seed=seed).random(count)
    return xt, np.sin(4 * xt[:, 0]) + xt[:, 1] ** 2


def test_leave_one_out_in_closed_form_is_each_run_predicted_from_the_others():
    """Dubrule's closed form against the GP refitted without each run (the
    same hyperparameters): its mean, and its variance with the nugget."""
    xt, y = smooth_runs(12)
    h = Hyperparameters(mean=0.2, sd=0.9, length_scale=np.array([0.5, 0.7]), nugget=0.02)
    expected = []
    for i in range(len(y)):
        others = np.delete(np.arange(len(y)), i)
        mean, variance = GaussianProcess(h, xt[others], y[others]).predict(xt[i : i + 1])
        expected.append((y[i] - mean[0]) / np.sqrt(variance[0] + h.nugget**2 + JITTER * h.sd**2))
    assert leave_one_out(GaussianProcess(h, xt, y)) == pytest.approx(np.array(expected), rel=1e-6)


def test_an_overconfident_gp_is_inflated_by_its_mean_squared_error():
    """A GP's covariance shrunk by c^2 (sd and nugget over c) keeps its mean
    and divides every variance by c^2: its leave-one-out errors are c times
    larger exactly, so its check inflates the variance by their mean square,
    at least c^2 times the sound GP's; after it, the predictive variance is
    that many times larger."""
    xt, y = smooth_runs()
    sound = GaussianProcess.fit(xt, y, seed=1)
    h, c = sound.hyperparameters, 5.0
    shrunk = GaussianProcess(Hyperparameters(h.mean, h.sd / c, h.length_scale, h.nugget / c), xt, y)
    assert leave_one_out(shrunk) == pytest.approx(c * leave_one_out(sound), rel=1e-6)
    result = check(shrunk, seed=1)
    loo_mean_square = np.mean(leave_one_out(shrunk) ** 2)
    assert loo_mean_square == pytest.approx(c**2 * np.mean(leave_one_out(sound) ** 2))
    assert result.inflation == pytest.approx(loo_mean_square)  # far above what refitted folds ask for
    point = np.array([[0.3, 0.6]])
    before = shrunk.predict(point)[1]
    emulator, summaries = checked(ScalarEmulator(shrunk, 0.0, 1.0), seed=1)
    assert summaries[0]["inflation"] == pytest.approx(result.inflation)
    assert emulator.gp.predict(point)[1] == pytest.approx(result.inflation * before)


def test_the_inflation_is_the_larger_mean_square_and_at_least_one():
    assert Check(np.array([2.0, 0.0]), np.array([1.0, 1.0])).inflation == pytest.approx(2.0)
    assert Check(np.array([0.5, 0.5]), np.array([1.0, 3.0])).inflation == pytest.approx(5.0)
    repeated = np.array([[1.0, 3.0], [1.0, 1.0]])  # two partitions: the mean square over both
    assert Check(np.array([0.5, 0.5]), repeated).inflation == pytest.approx(3.0)
    assert Check(np.array([0.5, 0.5]), np.array([0.1, 0.2])).inflation == 1.0


def test_k_fold_refits_the_hyperparameters_without_each_fold():
    """A fold's errors are those of a GP fitted (hyperparameters too) on the
    other folds, with its nugget; the folds cover every run once."""
    xt, y = smooth_runs(20)
    gp = GaussianProcess.fit(xt, y, seed=1)
    errors = k_fold(gp, seed=4, folds=4)
    held = np.array_split(np.random.default_rng(4).permutation(20), 4)[1]
    fitted = GaussianProcess.fit(xt[np.setdiff1d(np.arange(20), held)], y[np.setdiff1d(np.arange(20), held)], 4)
    mean, variance = fitted.predict(xt[held])
    expected = (y[held] - mean) / np.sqrt(variance + fitted.hyperparameters.nugget**2)
    assert errors[held] == pytest.approx(expected, rel=1e-8)
    assert np.all(np.isfinite(errors))


def test_a_waves_cut_uses_its_inflated_variance_and_later_waves_rebuild_it(toy_match):
    """history_match checks its emulator: the wave records each check, and
    the cut rebuilt from waves.json (to_dict, json) has the same inflated
    variance, so the implausibility is |z - m| / sqrt(inflation v + d^2 + e^2)."""
    match = toy_match
    wave = match.waves[-1]
    assert wave.checks and {"loo_rms", "k_fold_rms", "inflation"} <= set(wave.checks[0])
    stored = Wave(**json.loads(json.dumps(wave.to_dict())))
    rebuilt = stored.cut(match.targets)
    assert rebuilt.emulator.gp.inflation == pytest.approx(wave.checks[0]["inflation"])
    theta = np.array([[0.3, 0.6], [0.6, 0.3]])
    assert rebuilt(theta) == pytest.approx(match.cuts[-1](theta), rel=1e-10)


def test_an_overconfident_emulator_rules_out_less_once_checked():
    """On a tiny case with a known answer: the shrunk GP of the test above
    in a cut, before and after its check. The implausibility at a theta is
    |z - m| / sqrt(v + d^2 + e^2) with v the inflated variance."""
    xt, y = smooth_runs()
    sound = GaussianProcess.fit(xt, y, seed=1)
    h = sound.hyperparameters
    shrunk = GaussianProcess(Hyperparameters(h.mean, h.sd / 5, h.length_scale, h.nugget / 5), xt, y)
    targets = Targets(np.array([[0.5]]), np.array([2.0]), np.array([0.01]), 0.0001, "given", "given")
    theta = np.array([[0.2]])
    mean, variance = shrunk.predict(np.array([[0.5, 0.2]]))
    before = Cut(ScalarEmulator(shrunk, 0.0, 1.0), targets, 1, 3.0)(theta)[0]
    emulator, summaries = checked(emulator_from_dict(ScalarEmulator(shrunk, 0.0, 1.0).to_dict()), seed=1)
    after = Cut(emulator, targets, 1, 3.0)(theta)[0]
    inflation = summaries[0]["inflation"]
    assert before == pytest.approx(abs(2.0 - mean[0]) / np.sqrt(variance[0] + 0.0101))
    assert after == pytest.approx(abs(2.0 - mean[0]) / np.sqrt(inflation * variance[0] + 0.0101))
    assert after < before
