"""Stage 1 of modular calibration for vector output (Higdon et al. 2008,
section 2.2): one GP per component weight of the runs' reduced basis
(stancal.problem.output_basis), over the simulator inputs and theta.

Each component's hyperparameters are emulator.stan's posterior mode (the
priors of the scalar path, which suit the weights: unit variance by
construction), found by scipy's L-BFGS on a random subset of at most
HYPERPARAMETER_RUNS runs (stancal.numerics.scalable_emulator.fit_hyperparameters);
the weights' predictive means then condition on all runs (one N x N
factorisation per component, once). Their predictive covariances
condition on a fixed random subset of at most VARIANCE_RUNS runs (the
subset of data approximation; Quinonero-Candela & Rasmussen 2005, section
9): the sampler forms them at every gradient, so that O(N^2) per component
becomes O(VARIANCE_RUNS^2), and a GP given fewer runs is never more
certain, so the bands can only widen. The components are independent a
priori and their weights uncorrelated over the runs, so the GPs are too;
the output's predictive variance adds the basis truncation error (and,
off the runs' grid, its interpolation error). The
weights' predictive variance keeps each GP's nugget, as Higdon et al.
(2008) and SEPIA do: the emulator is then no surer near its runs than
their jitter allows (left out, chains of a fit without a discrepancy
settled in the theta box's corners: docs/vector.md)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from stancal.numerics.scalable_emulator import Hyperparameters, fit_hyperparameters, run_covariance, se_correlation
from stancal.problem.output_basis import OutputBasis

HYPERPARAMETER_RUNS = 400  # per component: the mode moves little beyond a few hundred runs
VARIANCE_RUNS = 400  # the weights' covariance conditions on this many runs at most


def same_point(points: np.ndarray) -> np.ndarray:
    """(n, n) boolean: True where two of the n points are identical, so they
    share one draw of the weight GPs' nugget (the simulator is
    deterministic). Grouped exactly, as latent_data groups replicates."""
    _, group = np.unique(points, axis=0, return_inverse=True)
    group = group.ravel()  # numpy 2.0.0 gave the inverse the input's rank
    return group[:, None] == group[None, :]


@dataclass
class ComponentGP:
    hyperparameters: Hyperparameters
    variance_factor: tuple[np.ndarray, bool]  # Cholesky of the variance runs' covariance
    alpha: np.ndarray  # K^-1 (w - m), all runs

    def predict(self, xt_runs: np.ndarray, variance_runs: np.ndarray, points: np.ndarray,
                same: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Mean (given all runs) and covariance (given the variance runs) of
        the weight at the points, as component_weights in
        functions/vector_output.stan: the nugget, the runs' jitter about a
        smooth GP, is the simulator's at the points too (Higdon et al. 2008),
        one jitter at identical points (``same``, same_point(points) unless
        given: the simulator is deterministic)."""
        h = self.hyperparameters
        cross = h.sd**2 * se_correlation(points, xt_runs, h.length_scale)
        cross_variance = cross[:, variance_runs]
        same = same_point(points) if same is None else same
        covariance = (h.sd**2 * se_correlation(points, points, h.length_scale) + h.nugget**2 * same
                      - cross_variance @ linalg.cho_solve(self.variance_factor, cross_variance.T))
        return h.mean + cross @ self.alpha, covariance


@dataclass
class VectorEmulator:
    basis: OutputBasis
    xt_runs: np.ndarray  # (N, D + Q): inputs and theta of each run, unit cube
    components: list[ComponentGP]
    hyperparameter_runs: int
    variance_runs: np.ndarray  # indices of the runs the weights' covariance conditions on

    @classmethod
    def fit(cls, basis: OutputBasis, xt_runs: np.ndarray, run_outputs: np.ndarray, seed: int,
            hyperparameter_runs: int = HYPERPARAMETER_RUNS,
            variance_runs: int = VARIANCE_RUNS) -> VectorEmulator:
        """``xt_runs`` (N, D + Q) on the unit cube, ``run_outputs`` (N, K) on the basis's grid."""
        scores = basis.weights(run_outputs)
        chosen = np.sort(np.random.default_rng(seed).choice(len(xt_runs), min(variance_runs, len(xt_runs)),
                                                            replace=False))
        components = []
        for j in range(basis.count):
            h, used = fit_hyperparameters(xt_runs, scores[:, j], seed + j, subset=hyperparameter_runs)
            factor = linalg.cho_factor(run_covariance(xt_runs, h), lower=True)
            alpha = linalg.cho_solve(factor, scores[:, j] - h.mean)
            del factor  # N x N: only the variance runs' factor is kept
            components.append(ComponentGP(h, linalg.cho_factor(run_covariance(xt_runs[chosen], h), lower=True),
                                          alpha))
        return cls(basis, xt_runs, components, used, chosen)

    def weights(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predictive means and variances (points, p) of the component weights."""
        same = same_point(points)  # one grouping for every component
        predicted = [gp.predict(self.xt_runs, self.variance_runs, points, same) for gp in self.components]
        return (np.column_stack([m for m, _ in predicted]),
                np.column_stack([np.maximum(np.diag(v), 0.0) for _, v in predicted]))

    def predict(self, points: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The output's predictive mean and variance at each point's
        indices: (points, M) for M output indices shared by the points."""
        return self.basis.predict(indices, *self.weights(points))
