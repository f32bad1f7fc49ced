"""Each wave's emulator of the simulator, with its predictive mean and
variance at new (x, theta) and no Stan: for a scalar output the GP of
emulator.stan at its posterior mode (stancal.numerics.scalable_emulator),
for a vector output one such GP per component weight of the runs' basis
(Higdon et al. 2008; stancal.numerics.vector_emulator). A wave keeps what
defines its emulator (the runs it was fitted on, its hyperparameters and
basis) so that later waves rebuild it exactly, with no optimisation."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import linalg

from stancal.designing.targets import run_table
from stancal.numerics.scalable_emulator import (
    Hyperparameters,
    fit_hyperparameters,
    predictive_mean_variance,
    run_factor,
    se_correlation,
    whitener,
)
from stancal.problem.output_basis import OutputBasis


@dataclass
class GaussianProcess:
    """A GP of standardised values over (x, theta) on the unit cube. Its
    predictive variance is multiplied by ``inflation``: 1, or what its
    check asked for (stancal.designing.emulator_checks)."""

    hyperparameters: Hyperparameters
    xt_runs: np.ndarray
    values: np.ndarray
    inflation: float = 1.0

    def __post_init__(self) -> None:
        self.factor = run_factor(self.xt_runs, self.hyperparameters)
        self.alpha = linalg.cho_solve(self.factor, self.values - self.hyperparameters.mean)
        self.inverse_factor = whitener(self.factor)

    @classmethod
    def fit(cls, xt_runs: np.ndarray, values: np.ndarray, seed: int) -> GaussianProcess:
        return cls(fit_hyperparameters(xt_runs, values, seed)[0], xt_runs, values)

    def predict(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        mean, variance = predictive_mean_variance(points, self.xt_runs, self.alpha, self.hyperparameters,
                                                  self.inverse_factor)
        return mean, self.inflation * variance

    def covariance(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The predictive covariance between the rows of a and b given the
        runs, no nugget at them (as ``predict``'s variance): k(a, b) - k(a, X)
        K^-1 k(X, b), through the stored whitener, one product per side."""
        h = self.hyperparameters
        whitened_a = h.sd**2 * se_correlation(a, self.xt_runs, h.length_scale) @ self.inverse_factor.T
        whitened_b = h.sd**2 * se_correlation(b, self.xt_runs, h.length_scale) @ self.inverse_factor.T
        return self.inflation * (h.sd**2 * se_correlation(a, b, h.length_scale) - whitened_a @ whitened_b.T)

    def to_dict(self) -> dict:
        return {"hyperparameters": self.hyperparameters.as_stan(), "inflation": self.inflation}


def pairs(x_unit: np.ndarray, theta_unit: np.ndarray) -> np.ndarray:
    """Every (theta_s, x_i): (S * n, D + Q), theta's index varying slowest."""
    S, n = len(theta_unit), len(x_unit)
    return np.column_stack([np.tile(x_unit, (S, 1)), np.repeat(theta_unit, n, axis=0)])


@dataclass
class ScalarEmulator:
    """One GP of the standardised output: y = center + scale * GP."""

    gp: GaussianProcess
    center: float
    scale: float

    @classmethod
    def fit(cls, xt_runs: np.ndarray, y: np.ndarray, seed: int) -> ScalarEmulator:
        center, scale = float(y.mean()), float(y.std()) or 1.0
        return cls(GaussianProcess.fit(xt_runs, (y - center) / scale, seed), center, scale)

    def at(self, x_unit: np.ndarray, theta_unit: np.ndarray, groups=(), group_theta=None) -> tuple[np.ndarray,
                                                                                               np.ndarray]:
        """Mean and variance (S, n) in output units at every theta and x
        (``group_theta``: per-experiment theta, a vector output's only)."""
        mean, variance = self.gp.predict(pairs(x_unit, theta_unit))
        shape = (len(theta_unit), len(x_unit))
        return (self.center + self.scale * mean).reshape(shape), (self.scale**2 * variance).reshape(shape)

    def parts(self, groups=()) -> list[tuple[GaussianProcess, float]]:
        """The GPs and the output variance per unit of each (for variance reduction)."""
        return [(self.gp, self.scale**2)]

    def to_dict(self) -> dict:
        return {"kind": "scalar", "xt_runs": self.gp.xt_runs.tolist(), "y": (self.center + self.scale
                * self.gp.values).tolist(), "center": self.center, "scale": self.scale, **self.gp.to_dict()}

    @classmethod
    def from_dict(cls, d: dict) -> ScalarEmulator:
        xt, y = np.asarray(d["xt_runs"], float), np.asarray(d["y"], float)
        gp = GaussianProcess(Hyperparameters.from_stan(d["hyperparameters"]), xt, (y - d["center"]) / d["scale"],
                             d.get("inflation", 1.0))  # waves.json written before the checks: none
        return cls(gp, d["center"], d["scale"])


@dataclass
class BasisEmulator:
    """One GP per component weight of the output basis: y(index) =
    mean(index) + scale * components(index) @ w, each weight's variance with
    its GP's nugget, plus the basis's truncation error (and, off its grid,
    interpolation error), as stancal.numerics.vector_emulator."""

    basis: OutputBasis
    gps: list[GaussianProcess]
    outputs: np.ndarray  # (runs, K): the runs' outputs on the basis's grid

    @classmethod
    def fit(cls, basis: OutputBasis, xt_runs: np.ndarray, outputs: np.ndarray, seed: int) -> BasisEmulator:
        scores = basis.weights(outputs)
        return cls(basis, [GaussianProcess.fit(xt_runs, scores[:, j], seed + j) for j in range(basis.count)],
                   outputs)

    def at(self, x_unit: np.ndarray, theta_unit: np.ndarray, groups, group_theta=None) -> tuple[np.ndarray,
                                                                                             np.ndarray]:
        """Mean and variance (S, n) at every theta and observed value, one
        experiment (``groups``: its inputs, values and output indices) at a
        time; ``group_theta``: each experiment's own theta (S, Q) in place of
        ``theta_unit`` (per-experiment theta)."""
        mean = np.empty((len(theta_unit), len(x_unit)))
        variance = np.empty_like(mean)
        for g, (row, values, indices) in enumerate(groups):
            theta = theta_unit if group_theta is None else group_theta[g]
            points = np.column_stack([np.broadcast_to(row, (len(theta), len(row))), theta])
            predicted = [gp.predict(points) for gp in self.gps]
            weight_mean = np.column_stack([m for m, _ in predicted])
            # each weight's nugget too, as stage 1's emulator keeps it (ComponentGP.predict; Higdon et al. 2008)
            weight_variance = np.column_stack([v + gp.hyperparameters.nugget**2
                                               for (_, v), gp in zip(predicted, self.gps, strict=True)])
            mean[:, values], variance[:, values] = self.basis.predict(indices, weight_mean, weight_variance)
        return mean, variance

    def parts(self, groups=()) -> list[tuple[GaussianProcess, float]]:
        """Each component's GP and its output variance per unit weight,
        averaged over the observed output indices (``groups``, as ``at``
        takes them), or over the grid without them: the variance that
        matters is where the data are, not where the runs' grid is dense."""
        if groups:
            columns = self.basis.grid.shape[1]
            observed = np.vstack([np.asarray(indices, float).reshape(-1, columns) for _, _, indices in groups])
            components = self.basis.at(observed)[1]
        else:
            components = self.basis.components
        return [(gp, float(self.basis.scale**2 * np.mean(components[:, j] ** 2))) for j, gp in enumerate(self.gps)]

    def to_dict(self) -> dict:
        basis = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in asdict(self.basis).items()}
        return {"kind": "vector", "xt_runs": self.gps[0].xt_runs.tolist(), "outputs": self.outputs.tolist(),
                "basis": basis, "components": [gp.to_dict() for gp in self.gps]}

    @classmethod
    def from_dict(cls, d: dict) -> BasisEmulator:
        # to_dict's inverse: its arrays were written as lists, its floats as they are
        basis = OutputBasis(**{k: np.asarray(v, float) if isinstance(v, list) else v for k, v in d["basis"].items()})
        xt, outputs = np.asarray(d["xt_runs"], float), np.asarray(d["outputs"], float)
        scores = basis.weights(outputs)
        gps = [GaussianProcess(Hyperparameters.from_stan(c["hyperparameters"]), xt, scores[:, j],
                               c.get("inflation", 1.0)) for j, c in enumerate(d["components"])]
        return cls(basis, gps, outputs)


def emulator_from_dict(d: dict) -> ScalarEmulator | BasisEmulator:
    return ScalarEmulator.from_dict(d) if d["kind"] == "scalar" else BasisEmulator.from_dict(d)


def calibration_emulator(data, box, stage_one) -> ScalarEmulator | BasisEmulator | None:
    """The emulator a modular calibration of ``data`` used (its stage 1:
    every run, its hyperparameters; Liu, Bayarri & Berger 2009), on the
    design's unit box ``box`` (a UnitBox), or None without a stage 1. The
    calibration's unit cube spans the inputs over the physical data's and
    the runs' range, the box over the physical data's: a length scale in
    one is the other's times the ratio of the widths, so the GP is the same.
    ``stage_one``: a scalar result's ``emulator`` dict, or a vector result's
    VectorEmulator. The vector one is conditioned here on every run for its
    variance (stage 1 on at most its VARIANCE_RUNS; the same below that).
    A multi-fidelity stage 1 gives None too: the design's emulators are of
    the calibrated simulator's runs alone."""
    scaling = data.scaling
    factor = np.array([scaling.width[c] for c in box.columns]) / box.width

    def on_box(h: Hyperparameters) -> Hyperparameters:
        return Hyperparameters(h.mean, h.sd, h.length_scale * factor, h.nugget)

    if isinstance(stage_one, dict):
        hyperparameters = stage_one.get("hyperparameters")
        if hyperparameters is None or "levels" in hyperparameters:
            return None
        h = on_box(Hyperparameters.from_stan(hyperparameters))
        xt, y = run_table(data, box)
        return ScalarEmulator(GaussianProcess(h, xt, scaling.standardise(y)), scaling.y_center, scaling.y_scale)
    if stage_one is None or stage_one.fidelities > 1:
        return None
    xt, outputs = run_table(data, box)
    scores = stage_one.basis.weights(outputs)
    gps = [GaussianProcess(on_box(c.hyperparameters), xt, scores[:, j]) for j, c in enumerate(stage_one.components)]
    return BasisEmulator(stage_one.basis, gps, outputs)
