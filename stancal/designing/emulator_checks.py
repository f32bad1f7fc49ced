"""Each wave's emulator is checked before it rules anything out
(Bastos & O'Hagan 2009, "Diagnostics for Gaussian process emulators",
Technometrics 51(4)): its standardised errors, (y - E[y]) / sd, at runs it
did not see should look like standard normal draws. When they are larger,
its variance is too small, and a cut with it rules out theta the simulator
would not: its variance is multiplied by their mean square (when above 1),
the factor that makes their mean square 1.

Two sets of held-out errors, each of every run:

- leave-one-out at the fitted hyperparameters, in closed form (Dubrule
  1983, "Cross validation of kriging in a unique neighborhood", Math.
  Geology 15): with K the runs' covariance, the left-out run's error is
  [K^-1 (y - m)]_i / [K^-1]_ii and its variance 1 / [K^-1]_ii;
- K-fold, the hyperparameters refitted without each fold, repeated over
  PARTITIONS random partitions. Leave-one-out keeps the hyperparameters
  fitted on every run, so it cannot see that they are poorly determined
  by few runs in many dimensions; refitted, the held-out errors carry
  that uncertainty. On the pin fin (docs/design.md) leave-one-out gave a
  mean square near 1 while the emulator missed the simulator at the true
  theta by up to 5 sds; 5-fold gave 0.9 to 2.7 on the same 40 runs by the
  partition alone (a few large errors dominate it), so the mean square is
  averaged over partitions (repeated cross-validation, Burman 1989,
  "A comparative study of ordinary cross-validation, v-fold
  cross-validation and the repeated learning-testing methods",
  Biometrika 76).

The inflation is the larger mean square, at least 1."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stancal.designing.emulators import GaussianProcess

FOLDS = 5  # K-fold: each fit leaves out a fifth of the runs
PARTITIONS = 3  # K-fold repeated over this many partitions: its mean square varies by a factor 3 between them


@dataclass
class Check:
    """One GP's held-out standardised errors and the inflation they ask for."""

    leave_one_out: np.ndarray
    k_fold: np.ndarray  # (partitions, runs): each partition's errors of every run

    @property
    def inflation(self) -> float:
        return max(1.0, mean_square(self.leave_one_out), mean_square(self.k_fold))

    def summary(self) -> dict:
        return {"loo_rms": float(np.sqrt(mean_square(self.leave_one_out))),
                "loo_beyond_3": int(np.sum(np.abs(self.leave_one_out) > 3)),
                "k_fold_rms": float(np.sqrt(mean_square(self.k_fold))),
                "k_fold_beyond_3": float(np.mean(np.sum(np.abs(self.k_fold) > 3, axis=-1))),  # per partition
                "inflation": self.inflation}


def mean_square(errors: np.ndarray) -> float:
    return float(np.mean(errors**2))


def leave_one_out(gp: GaussianProcess) -> np.ndarray:
    """The standardised leave-one-out errors at the GP's runs, closed form
    (Dubrule 1983), its hyperparameters held: the variance is the GP's for a
    run's value, the nugget included, as the run's value was fitted with it."""
    # the GP holds alpha = K^-1 (y - m) and L^-1, so [K^-1]_ii = sum_k (L^-1)_ki^2: no refactorisation
    return gp.alpha / np.sqrt(np.sum(gp.inverse_factor**2, axis=0))


def k_fold(gp: GaussianProcess, seed: int, folds: int = FOLDS) -> np.ndarray:
    """The standardised errors of each fold's runs under a GP fitted
    (hyperparameters too) on the other folds; the folds a random partition."""
    order = np.random.default_rng(seed).permutation(len(gp.values))
    errors = np.empty(len(gp.values))
    for held in np.array_split(order, min(folds, len(order))):
        kept = np.setdiff1d(order, held)
        fitted = GaussianProcess.fit(gp.xt_runs[kept], gp.values[kept], seed)
        mean, variance = fitted.predict(gp.xt_runs[held])
        variance = variance + fitted.hyperparameters.nugget**2
        errors[held] = (gp.values[held] - mean) / np.sqrt(variance)
    return errors


def check(gp: GaussianProcess, seed: int, partitions: int = PARTITIONS) -> Check:
    return Check(leave_one_out(gp), np.array([k_fold(gp, seed + 1000 * p) for p in range(partitions)]))


def checked(emulator, seed: int) -> tuple[object, list[dict]]:
    """``emulator`` (a ScalarEmulator or BasisEmulator) with each GP's
    variance inflated by its check (GaussianProcess.inflation), and each
    check's summary."""
    summaries = []
    for j, (gp, _) in enumerate(emulator.parts()):
        result = check(gp, seed + j)
        gp.inflation = result.inflation
        summaries.append(result.summary())
    return emulator, summaries
