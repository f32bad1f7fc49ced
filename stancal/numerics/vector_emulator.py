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
9; with cheaper runs, every calibrated simulator's run first:
variance_subset): the sampler forms them at every gradient, so that O(N^2)
per component becomes O(VARIANCE_RUNS^2), and a GP given fewer runs is never more
certain, so the bands can only widen. The components are independent a
priori and their weights uncorrelated over the runs, so the GPs are too;
the output's predictive variance adds the basis truncation error (and,
off the runs' grid, its interpolation error). The
weights' predictive variance keeps each GP's nugget, as Higdon et al.
(2008) and SEPIA do: the emulator is then no surer near its runs than
their jitter allows (left out, chains of a fit without a discrepancy
settled in the theta box's corners: docs/vector.md).

With runs of cheaper simulators too (VectorEmulator.fit_fidelities;
docs/multifidelity.md), the basis stays the calibrated simulator's runs'
and each component weight gets the autoregressive emulator of Kennedy &
O'Hagan (2000), fitted level by level as Le Gratiet & Garnier (2014) do
(stancal.numerics.multifidelity, constant rho per component), the cheaper
runs entering as their projections on the basis; its top level's variance
is scaled for its hyperparameters' uncertainty as the scalar path's is
(stancal.numerics.multifidelity_variance)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from stancal.numerics.multifidelity import (
    CheapRunsValue,
    Level,
    cheap_runs_value,
    cross_covariance,
    fit_levels,
    joint_covariance,
    level_covariance,
    level_mean,
    stacked_residuals,
)
from stancal.numerics.multifidelity_variance import variance_correction
from stancal.numerics.scalable_emulator import (
    Hyperparameters,
    fit_hyperparameters,
    run_covariance,
    same_point,
    se_correlation,
)
from stancal.problem.output_basis import OutputBasis

HYPERPARAMETER_RUNS = 400  # per component: the mode moves little beyond a few hundred runs
VARIANCE_RUNS = 400  # the weights' covariance conditions on this many runs at most
# A component under 1 % of the runs' variance moves the output by a tenth (sqrt(0.01)) of the runs' sd
# at most: its emulator's error, with or without the cheap runs, is not one to warn of.
MATERIAL_SHARE = 0.01


@dataclass
class ComponentGP:
    hyperparameters: Hyperparameters
    variance_factor: tuple[np.ndarray, bool]  # Cholesky of the variance runs' covariance
    alpha: np.ndarray  # K^-1 (w - m), all runs

    @property
    def prior_variance(self) -> float:
        """The weight's prior variance without the nugget: the likelihood's jitter scale (modular_vector.stan)."""
        return float(self.hyperparameters.sd**2)

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
class FidelityComponentGP:
    """One component weight's emulator given runs of several fidelities
    (Kennedy & O'Hagan 2000): its levels, cheapest first, with the runs'
    weights; predicts the top level, as fidelity_component_weights in
    functions/vector_fidelity.stan."""

    levels: list[Level]
    variance_factor: tuple[np.ndarray, bool]  # Cholesky of the variance runs' covariance (every level's runs)
    alpha: np.ndarray  # K^-1 (w - each run's level mean), every run, cheapest level's first
    value: CheapRunsValue | None  # rho and the leave-one-out errors with and without the cheaper runs (fitted)
    variance_factor_applied: float  # the factor on the top level's own variance (multifidelity_variance)

    @classmethod
    def conditioned(cls, levels: list[Level], chosen: np.ndarray, value: CheapRunsValue | None = None,
                    applied: float = 1.0) -> FidelityComponentGP:
        """The emulator given every level's runs, its covariance given the
        runs ``chosen`` (indices among every level's, cheapest first), with
        the jitter of fidelity_run_cov in functions/fidelity.stan."""
        covariance = joint_covariance(levels, top_jitter=True)
        alpha = linalg.cho_solve(linalg.cho_factor(covariance, lower=True), stacked_residuals(levels))
        return cls(levels, linalg.cho_factor(covariance[np.ix_(chosen, chosen)], lower=True), alpha, value, applied)

    @property
    def hyperparameters(self) -> Hyperparameters:
        """The top level's own GP g_L (modular_vector.stan's emulator_*)."""
        return self.levels[-1].hyperparameters

    @property
    def prior_variance(self) -> float:
        """The top level's prior variance without the nugget, every level's
        share in it (fidelity_variance in functions/fidelity.stan, constant
        rho): the likelihood's jitter scale (modular_vector.stan)."""
        variance = 0.0
        for level in self.levels:  # the cheapest's rho is unused: it scales nothing
            variance = level.rho**2 * variance + level.hyperparameters.sd**2
        return float(variance)

    def predict(self, xt_runs: np.ndarray, variance_runs: np.ndarray, points: np.ndarray,
                same: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Mean (given every run) and covariance (given the variance runs) of
        the top level's weight at the points, with the top level's own nugget
        at identical points (ComponentGP.predict's rule); ``xt_runs``: every
        level's runs stacked, as the levels hold them."""
        top = len(self.levels) - 1
        cross = cross_covariance(self.levels, points, top)
        cross_variance = cross[:, variance_runs]
        same = same_point(points) if same is None else same
        covariance = (level_covariance(self.levels, points, top, points, top) + self.hyperparameters.nugget**2 * same
                      - cross_variance @ linalg.cho_solve(self.variance_factor, cross_variance.T))
        return level_mean(self.levels, top, points) + cross @ self.alpha, covariance


def fit_fidelity_component(xt_levels: list[np.ndarray], weights: list[np.ndarray], chosen: np.ndarray,
                           seed: int) -> FidelityComponentGP:
    """One component's levels at their posterior mode, level by level (Le
    Gratiet & Garnier 2014), the top level's variance scaled for its
    hyperparameters' uncertainty, and the factors modular_vector.stan takes
    (its runs' covariance with fidelity_run_cov's jitter)."""
    correction = variance_correction(fit_levels(xt_levels, weights, seed), seed)
    return FidelityComponentGP.conditioned(correction.levels, chosen, cheap_runs_value(correction.levels, seed),
                                           correction.applied)


def variance_subset(run_level: np.ndarray, variance_runs: int, seed: int) -> np.ndarray:
    """The runs the weights' covariance conditions on: all, or
    ``variance_runs`` of them, the costliest level's first: every run of the
    top level (the calibrated simulator's), then each level below in turn,
    the level that fills the last slots drawn at random. A draw over every
    level at once left some expensive runs out among hundreds of cheap ones,
    and the bands there widened tenfold (600 + 12 runs: 3 of 12 left out,
    sd 0.04 to 0.14 against 0.014). ``run_level``: each run's level, 0 the
    cheapest (all 0 for one fidelity)."""
    rng = np.random.default_rng(seed)
    chosen, room = [], variance_runs
    for level in np.unique(run_level)[::-1]:
        runs = np.flatnonzero(run_level == level)
        chosen.append(runs if len(runs) <= room else rng.choice(runs, room, replace=False))
        room -= len(chosen[-1])
    return np.sort(np.concatenate(chosen))


@dataclass
class VectorEmulator:
    basis: OutputBasis
    xt_runs: np.ndarray  # (N, D + Q): inputs and theta of each run (every level's, cheapest first), unit cube
    components: list[ComponentGP] | list[FidelityComponentGP]
    hyperparameter_runs: int
    variance_runs: np.ndarray  # indices of the runs the weights' covariance conditions on
    run_level: np.ndarray | None = None  # (N,) each run's level from 0, the cheapest; None: one fidelity
    run_weights: np.ndarray | None = None  # (N, p) each run's component weights (the cheaper runs' projected)

    @property
    def fidelities(self) -> int:
        """The levels of the runs: 1, or more with cheaper simulators' runs."""
        return 1 if self.run_level is None else int(self.run_level.max()) + 1

    def fidelity_summary(self) -> dict | None:
        """Per component: each level's scale on the one below, the leave-one-out
        error at the calibrated simulator's runs with and without the cheaper
        runs (standardised weights) and the factor on the top level's own
        variance; None with one fidelity."""
        if self.fidelities == 1:
            return None
        fitted = self._fitted_fidelity_components()
        return {"levels": self.fidelities,
                "level_rho": [gp.value.rho for gp in fitted],
                "loo_rmse": [gp.value.loo_with for gp in fitted],
                "loo_rmse_without_low_fidelity": [gp.value.loo_without for gp in fitted],
                "top_level_variance_factor": [gp.variance_factor_applied for gp in fitted],
                "warning": self.fidelity_warning()}

    def _fitted_fidelity_components(self) -> list[FidelityComponentGP]:
        """The components whose multi-fidelity fit measured the cheaper runs' value."""
        return [gp for gp in self.components if isinstance(gp, FidelityComponentGP) and gp.value is not None]

    def fidelity_warning(self) -> str | None:
        """One line when the cheaper runs do not help (issue 34, item 4): at
        the components that carry at least MATERIAL_SHARE of the runs'
        variance and are not helped (CheapRunsValue.warning), or at every
        component when none is helped; None with one fidelity or otherwise."""
        values = [gp.value for gp in self._fitted_fidelity_components()]
        if not values:
            return None
        share = self.basis.explained
        unhelped = [c for c, v in enumerate(values) if not v.helps]
        named = unhelped if len(unhelped) == len(values) else [c for c in unhelped if share[c] >= MATERIAL_SHARE]
        if not named:
            return None
        return "; ".join(f"component {c + 1} ({share[c]:.1%} of the runs' variance): {values[c].warning()}"
                         for c in named)

    @classmethod
    def fit(cls, basis: OutputBasis, xt_runs: np.ndarray, run_outputs: np.ndarray, seed: int,
            hyperparameter_runs: int = HYPERPARAMETER_RUNS,
            variance_runs: int = VARIANCE_RUNS) -> VectorEmulator:
        """``xt_runs`` (N, D + Q) on the unit cube, ``run_outputs`` (N, K) on the basis's grid."""
        scores = basis.weights(run_outputs)
        chosen = variance_subset(np.zeros(len(xt_runs), int), variance_runs, seed)
        components = []
        for j in range(basis.count):
            h, used = fit_hyperparameters(xt_runs, scores[:, j], seed + j, subset=hyperparameter_runs)
            factor = linalg.cho_factor(run_covariance(xt_runs, h), lower=True)
            alpha = linalg.cho_solve(factor, scores[:, j] - h.mean)
            del factor  # N x N: only the variance runs' factor is kept
            components.append(ComponentGP(h, linalg.cho_factor(run_covariance(xt_runs[chosen], h), lower=True),
                                          alpha))
        return cls(basis, xt_runs, components, used, chosen, run_weights=scores)

    @classmethod
    def fit_fidelities(cls, basis: OutputBasis, xt_levels: list[np.ndarray], weights: list[np.ndarray], seed: int,
                       variance_runs: int = VARIANCE_RUNS) -> VectorEmulator:
        """Runs of several fidelities, cheapest first: ``xt_levels`` each
        level's (runs, D + Q) on the unit cube, ``weights`` their component
        weights on ``basis`` (the calibrated simulator's; the cheaper runs
        projected on it, OutputBasis.project). One multi-fidelity emulator
        per component (fit_fidelity_component)."""
        xt_runs = np.vstack(xt_levels)
        run_level = np.concatenate([np.full(len(xt), k) for k, xt in enumerate(xt_levels)])
        chosen = variance_subset(run_level, variance_runs, seed)
        components = [fit_fidelity_component(xt_levels, [w[:, j] for w in weights], chosen, seed + j)
                      for j in range(basis.count)]
        return cls(basis, xt_runs, components, len(xt_runs), chosen, run_level, np.vstack(weights))

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
