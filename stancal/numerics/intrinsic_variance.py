"""A stochastic simulator's own (intrinsic) variance as a smooth function of
its inputs and theta, from the sample variances at its replicated settings:
stochastic kriging's variance model (Ankenman, Nelson & Staum 2010,
Operations Research 58(2), section 3.3: a second GP fitted to the log
sample variances), then carried on the emulator runs' diagonal
(stancal.numerics.scalable_emulator's ``known``, emulator.stan's and
modular.stan's ``run_intrinsic_sd``).

For normal replicates, log s^2 from n runs has mean log sigma^2 +
psi(k / 2) - log(k / 2) and variance psi'(k / 2), with k = n - 1
(Bartlett & Kendall 1946): the bias is removed and the variance becomes
each setting's known noise in that GP, so a setting of two runs counts less
than one of twenty. The log variances are standardised first (the GP's
priors are emulator.stan's, on a unit scale). The GP's hyperparameters are its posterior mode under
emulator.stan's priors (scalable_emulator.fit_hyperparameters); the
variance at a run is exp(the GP's mean there), the log variance's median.
A setting whose runs agree exactly has no log variance and is left to
the others. With fewer than MIN_SETTINGS replicated settings left, or log
variances all alike, no surface can be told from a level, and the pooled
variance is used at every run."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, special

from stancal.numerics.scalable_emulator import Hyperparameters, fit_hyperparameters, run_covariance, se_correlation
from stancal.problem.run_replicates import pooled_variance

MIN_SETTINGS = 4  # replicated settings for a variance surface; fewer: the pooled variance
SCALE_FLOOR = 1e-8  # log variances this alike (relative to their level) are one level: the pooled variance


def log_variance_moments(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """E[log s^2] - log sigma^2 and Var[log s^2] for normal samples of ``counts`` runs."""
    half = (np.asarray(counts, float) - 1) / 2
    return special.digamma(half) - np.log(half), special.polygamma(1, half)


@dataclass(frozen=True)
class IntrinsicVariance:
    """The intrinsic variance surface: a constant (``pooled``), or a GP on
    the replicated settings' bias-corrected log sample variances."""

    pooled: float  # the pooled within-replicate variance
    settings: np.ndarray  # (S, D + Q) replicated settings on the unit cube; empty for the constant
    centre: float = 0.0  # the corrected log variances' mean, taken out before the GP
    scale: float = 1.0  # and their sd, divided out (the GP's priors are on a unit scale)
    weights: np.ndarray | None = None  # K^-1 (log variances - centre - GP mean)
    hyperparameters: Hyperparameters | None = None

    @classmethod
    def fit(cls, settings: np.ndarray, counts: np.ndarray, variances: np.ndarray, seed: int) -> IntrinsicVariance:
        """From the replicated settings (unit cube), their runs and sample variances (n >= 2 each)."""
        counts, variances = np.asarray(counts, float), np.asarray(variances, float)
        pooled = pooled_variance(counts, variances)
        # a setting whose runs agree exactly (discrete output) has no log variance: the others carry the surface
        scattered = variances > 0
        settings, counts, variances = np.asarray(settings, float)[scattered], counts[scattered], variances[scattered]
        bias, noise = log_variance_moments(counts)
        corrected = np.log(variances) - bias
        centre, scale = (float(corrected.mean()), float(corrected.std())) if len(counts) else (0.0, 0.0)
        if len(counts) < MIN_SETTINGS or scale <= SCALE_FLOOR * max(1.0, abs(centre)):  # no surface but a level
            return cls(pooled, np.zeros((0, np.shape(settings)[1])))
        z, noise = (corrected - centre) / scale, noise / scale**2
        h, _ = fit_hyperparameters(settings, z, seed, known=noise)
        weights = linalg.solve(run_covariance(settings, h, noise), z - h.mean, assume_a="pos")
        return cls(pooled, np.asarray(settings, float), centre, scale, weights, h)

    def at(self, xt: np.ndarray) -> np.ndarray:
        """The intrinsic variance at (x, theta) points on the unit cube, (P,)."""
        if self.hyperparameters is None:
            return np.full(len(xt), self.pooled)
        h = self.hyperparameters
        z = h.mean + h.sd**2 * se_correlation(xt, self.settings, h.length_scale) @ self.weights
        log_variance = self.centre + self.scale * z
        return np.exp(log_variance)

    def to_json(self) -> dict:
        h = self.hyperparameters
        return {"pooled": self.pooled, "settings": self.settings.tolist(), "centre": self.centre, "scale": self.scale,
                "weights": None if self.weights is None else self.weights.tolist(),
                "hyperparameters": None if h is None else h.as_stan()}

    @classmethod
    def from_json(cls, stored: dict) -> IntrinsicVariance:
        h = stored.get("hyperparameters")
        settings = np.asarray(stored["settings"], float) if stored["settings"] else np.zeros((0, 0))
        return cls(float(stored["pooled"]), settings,
                   float(stored["centre"]), float(stored["scale"]),
                   None if stored["weights"] is None else np.asarray(stored["weights"]),
                   None if h is None else Hyperparameters.from_stan(h))
