"""The physical output as the likelihood sees it: Gaussian values (some of
them censored to a range), counts, or binomial successes out of trials."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from stancal.problem.codes import Censoring, Likelihood
from stancal.problem.validation import DataError, numeric_values, require_whole
from stancal.problem.validation import row_labels as _rows

LIKELIHOODS = {likelihood.name.lower(): likelihood for likelihood in Likelihood}


def likelihood_of(name: str) -> Likelihood:
    try:
        return LIKELIHOODS[name]
    except KeyError:
        raise DataError(f"likelihood must be one of {', '.join(LIKELIHOODS)}; got {name!r}") from None


@dataclass(frozen=True)
class Link:
    """A likelihood's link g: where the simulator's mean must lie, and g itself."""

    transform: Callable[[np.ndarray], np.ndarray]
    defined: Callable[[np.ndarray], np.ndarray]
    requirement: str
    scale: str  # what the discrepancy is measured in on this scale


_LOG = Link(np.log, lambda v: v > 0, "a mean count > 0 (log link)", "log of the mean count")
LINKS = {
    Likelihood.GAUSSIAN: Link(lambda v: v, lambda v: np.ones(v.shape, dtype=bool), "a real number",
                              "output units"),
    Likelihood.POISSON: _LOG,
    Likelihood.NEGBINOMIAL: _LOG,
    Likelihood.BINOMIAL: Link(lambda v: np.log(v / (1 - v)), lambda v: (v > 0) & (v < 1),
                              "a success probability strictly between 0 and 1 (logit link)",
                              "logit of the success probability"),
}


def _finite_or_empty(frame: pd.DataFrame, column: str, what: str) -> np.ndarray:
    """Numbers with NaN where empty (an open bound is an empty cell, not inf)."""
    values = numeric_values(frame, column, what)
    if np.isinf(values).any():
        raise DataError(f"{what}: column '{column}' has inf in "
                        f"{_rows(np.isinf(values), frame.index)}; leave the cell empty instead")
    return values


@dataclass(frozen=True)
class Observations:
    """One entry per physical row. ``value`` is NaN where censored;
    ``lower``/``upper`` are -inf/+inf where a side is open."""

    likelihood: Likelihood
    value: np.ndarray
    trials: np.ndarray  # binomial trials; zeros otherwise
    censoring: np.ndarray  # Censoring codes
    lower: np.ndarray
    upper: np.ndarray

    @property
    def is_gaussian(self) -> bool:
        return self.likelihood is Likelihood.GAUSSIAN

    @property
    def observed(self) -> np.ndarray:
        return self.censoring == Censoring.OBSERVED

    @property
    def any_censored(self) -> bool:
        return not self.observed.all()

    def log_density(self, rows: np.ndarray, mean: np.ndarray, noise_sd: np.ndarray | None = None,
                    phi: np.ndarray | None = None, nu: np.ndarray | None = None) -> np.ndarray:
        """log p(y_row | mean response) for draws (draws, rows) of the mean at
        the given rows, in original units: the likelihood of the Stan
        programs (observation_model.stan), for held-out scores. ``noise_sd``
        (gaussian) is shaped (draws, 1) or (draws, rows), ``phi``
        (negbinomial) and ``nu`` (gaussian, Student-t noise: exact rows take
        a Student-t density, functions/noise.stan) (draws, 1)."""
        from scipy import stats

        y = self.value[rows]
        if self.likelihood is Likelihood.POISSON:
            return stats.poisson.logpmf(y, mean)
        if self.likelihood is Likelihood.NEGBINOMIAL:
            return stats.nbinom.logpmf(y, phi, phi / (phi + mean))
        if self.likelihood is Likelihood.BINOMIAL:
            return stats.binom.logpmf(y, self.trials[rows], mean)
        code, lower, upper = self.censoring[rows], self.lower[rows], self.upper[rows]
        exact = (stats.norm.logpdf(np.nan_to_num(y), mean, noise_sd) if nu is None
                 else stats.t.logpdf(np.nan_to_num(y), nu, mean, noise_sd))
        below = stats.norm.logcdf(upper, mean, noise_sd)
        above = stats.norm.logsf(lower, mean, noise_sd)
        return np.select(
            [code == Censoring.OBSERVED, code == Censoring.LEFT, code == Censoring.RIGHT],
            [exact, below, above],
            # interval: log(Phi(upper) - Phi(lower))
            below + np.log1p(-np.exp(np.minimum(stats.norm.logcdf(lower, mean, noise_sd) - below, 0))))

    def counts_by_kind(self) -> dict[str, int]:
        """How many observations are exact and how many censored of each kind."""
        return {kind.name.lower(): int(np.sum(self.censoring == kind)) for kind in Censoring}


def _refuse_proportions(value: np.ndarray, output: str, trials: str | None, index: pd.Index, what: str) -> None:
    """Fractions in (0, 1) under a binomial likelihood are most likely
    observed proportions: say what the likelihood takes."""
    fractions = (value > 0) & (value < 1)
    if fractions.any():
        hint = (f"give the number of successes out of '{trials}'" if trials is not None else
                "give those counts with the trials column (trials = ...), or 0/1 outcomes")
        raise DataError(f"{what}: output column '{output}' holds fractions in {_rows(fractions, index)}: a binomial "
                        f"output counts successes; {hint}")


def read_observations(frame: pd.DataFrame, output: str, likelihood: str = "gaussian",
                      trials: str | None = None, lower: str | None = None,
                      upper: str | None = None, what: str = "physical data") -> Observations:
    """Validate the output (and trials or censoring bounds) for the likelihood."""
    kind = likelihood_of(likelihood)
    for key, column in (("trials", trials), ("lower", lower), ("upper", upper)):
        if column is not None and column not in frame.columns:
            raise DataError(f"{what}: the {key} column '{column}' is missing; available: {list(frame.columns)}")
    if trials is not None and kind is not Likelihood.BINOMIAL:
        raise DataError(f"trials = '{trials}' is for likelihood 'binomial'; got '{likelihood}'")
    if (lower is not None or upper is not None) and kind is not Likelihood.GAUSSIAN:
        raise DataError(f"censoring bounds (lower/upper) need likelihood 'gaussian'; got '{likelihood}'")
    value = _finite_or_empty(frame, output, what)
    n = len(frame)
    censoring = np.zeros(n, dtype=int)
    low, high = np.full(n, -np.inf), np.full(n, np.inf)
    n_trials = np.zeros(n)
    if kind is Likelihood.GAUSSIAN:
        if lower is not None:
            low = np.where(np.isnan(given := _finite_or_empty(frame, lower, what)), -np.inf, given)
        if upper is not None:
            high = np.where(np.isnan(given := _finite_or_empty(frame, upper, what)), np.inf, given)
        empty = np.isnan(value)
        unbounded = empty & np.isneginf(low) & np.isposinf(high)
        if unbounded.any():
            hint = ("give a lower or upper bound for a censored value, or drop the rows"
                    if lower or upper else "fill them, drop the rows, or name bound columns (lower/upper)")
            raise DataError(f"{what}: output column '{output}' is empty in "
                            f"{_rows(unbounded, frame.index)}; {hint}")
        crossed = empty & (low >= high)
        if crossed.any():
            raise DataError(f"{what}: censored {_rows(crossed, frame.index)} have lower >= upper "
                            f"('{lower}' >= '{upper}'); an exact value belongs in '{output}'")
        censoring[empty & np.isneginf(low)] = Censoring.LEFT
        censoring[empty & np.isposinf(high)] = Censoring.RIGHT
        censoring[empty & np.isfinite(low) & np.isfinite(high)] = Censoring.INTERVAL
        low[~empty], high[~empty] = -np.inf, np.inf  # rows with a value are exact
    else:
        if kind is Likelihood.BINOMIAL:
            _refuse_proportions(value, output, trials, frame.index, what)
        require_whole(value, output, frame.index, what, 0)
        if kind is Likelihood.BINOMIAL:
            if trials is None:  # binary outcomes
                n_trials = np.ones(n)
                above = value > 1
                if above.any():
                    raise DataError(f"{what}: output column '{output}' must be 0 or 1 without a trials "
                                    f"column; {_rows(above, frame.index)} exceed 1 "
                                    "(name the trials column with trials = ...)")
            else:
                n_trials = _finite_or_empty(frame, trials, what)
                require_whole(n_trials, trials, frame.index, what, 1)
                above = value > n_trials
                if above.any():
                    raise DataError(f"{what}: successes '{output}' exceed trials '{trials}' in "
                                    f"{_rows(above, frame.index)}")
    observed = censoring == Censoring.OBSERVED
    if observed.sum() < 2:
        raise DataError(f"{what}: only {int(observed.sum())} rows have an exact '{output}'; "
                        "calibration needs at least 2")
    return Observations(kind, value, n_trials.astype(int), censoring, low, high)
