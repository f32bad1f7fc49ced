"""Implausibility (Craig et al. 1996; Vernon et al. 2010, section 3.2): at
each observed value i,

    I_i(theta) = |z_i - E[f(x_i, theta)]| / sqrt(Var[f(x_i, theta)] + Var_discrepancy + Var_noise_i),

combined over the values by the n-th largest (Vernon et al. 2010 use the
second and third maximum so that one badly emulated or mis-measured value
cannot rule out theta alone). theta is implausible when the combination
exceeds the cutoff, 3 by default: by Pukelsheim's three-sigma rule (1994,
"The three sigma rule", Am. Stat. 48) at least 95 % of any unimodal
distribution lies within 3 sd, so a theta whose value lies further out is
ruled out whatever the error's shape."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import stats

from stancal.designing.emulators import BasisEmulator, ScalarEmulator
from stancal.designing.targets import Targets

logger = logging.getLogger("stancal")

AUTO_RISK = 0.05  # the chance of ruling out the true theta that chooses the n-th maximum


def nth_maximum_for(count: int, cutoff: float) -> int:
    """The smallest n in 1, 2, 3 whose n-th maximum of ``count`` independent
    standard normal |errors| exceeds ``cutoff`` with probability at most
    AUTO_RISK (a binomial tail, p = P(|Z| > cutoff)); 3 when none does,
    with a logged warning giving its risk. At cutoff 3: the maximum up to
    18 values, the second up to 131, the third up to 303."""
    p = 2 * stats.norm.sf(cutoff)
    for n in (1, 2, 3):
        if stats.binom.sf(n - 1, count, p) <= AUTO_RISK:
            return n
    # the design's warnings are logged (as waves.py's are): the 3rd maximum is still the best allowed,
    # so this is a caution on the result, not a fault to stop on
    logger.warning("design: with %d observed values no n-th maximum up to the 3rd keeps the chance of ruling "
                   "out the true theta within %.0f %% at cutoff %g; the 3rd maximum is used, and rules it out "
                   "with chance %.0f %% were the errors independent (raise --cutoff or [design] cutoff)",
                   count, 100 * AUTO_RISK, cutoff, 100 * stats.binom.sf(2, count, p))
    return 3


def nth_largest(values: np.ndarray, n: int) -> np.ndarray:
    """The n-th largest of each row (the largest for n = 1)."""
    n = min(n, values.shape[1])
    return -np.partition(-values, n - 1, axis=1)[:, n - 1]


@dataclass
class Cut:
    """One wave's cut: its emulator, the targets, the combination and cutoff."""

    emulator: ScalarEmulator | BasisEmulator
    targets: Targets
    nth: int
    cutoff: float

    def each(self, theta_unit: np.ndarray) -> np.ndarray:
        """I_i(theta): (S, n) at S points of theta's unit cube."""
        mean, variance = self.targets.emulate(self.emulator, theta_unit)
        return self.targets.standardised(mean, variance)

    def __call__(self, theta_unit: np.ndarray) -> np.ndarray:
        """The combined implausibility (S,)."""
        return nth_largest(self.each(theta_unit), self.nth)

    def at_runs(self, run_theta: np.ndarray) -> np.ndarray:
        """The cut at runs' theta (R, Q_runs): the combined implausibility,
        or with per-experiment theta the smallest over experiments of the
        n-th largest over that experiment's values at the run's theta. A run
        whose theta lies in NROY's projection for some experiment passes it
        (the n-th largest of a subset is at most the whole's), so refocusing
        keeps every run that may, and perhaps a few more."""
        t = self.targets
        if not t.group_theta:
            return self(run_theta)
        mean, variance = self.emulator.at(t.x_unit, run_theta, t.groups)
        each = t.standardised(mean, variance)
        return np.min([nth_largest(each[:, values], self.nth) for _, values, _ in t.groups], axis=0)


def combined(cuts: list[Cut], theta_unit: np.ndarray, at_runs: bool = False) -> np.ndarray:
    """Every wave's cut at once, on a common scale: the largest ratio of a
    wave's implausibility to its cutoff, times the last wave's cutoff (so
    theta is not ruled out exactly when it passes every wave's cut).
    ``at_runs``: ``theta_unit`` are runs' theta (Cut.at_runs), not NROY's."""
    ratio = np.max([(cut.at_runs(theta_unit) if at_runs else cut(theta_unit)) / cut.cutoff for cut in cuts], axis=0)
    return ratio * cuts[-1].cutoff
