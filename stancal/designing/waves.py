"""History matching in waves (Vernon et al. 2010; Williamson et al. 2013,
"History matching for exploring and reducing climate model parameter
space", Climate Dynamics 41): each wave fits an emulator to the runs that
earlier waves did not rule out (refocusing, as hmer's waves do) when at
least RUNS_PER_DIMENSION per dimension of (x, theta) lie there, else to
every run; it adds its cut and keeps every earlier cut; NROY is where
every cut passes.

A wave stores what defines its cut (its emulator's runs, hyperparameters
and basis; the discrepancy and noise variances; n-th maximum and cutoff):
later waves rebuild earlier cuts exactly from it, whatever the runs CSV
holds by then."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from stancal.designing.emulator_checks import checked
from stancal.designing.emulators import BasisEmulator, ScalarEmulator, emulator_from_dict
from stancal.designing.implausibility import Cut, combined, nth_maximum_for
from stancal.designing.nroy import NroySample, sample_nroy
from stancal.designing.targets import DesignSettings, Targets, UnitBox, run_table, targets_of
from stancal.problem.validation import DataError
from stancal.problem.vector_data import VectorCalibrationData

logger = logging.getLogger("stancal")

BULKY = ("emulator", "noise_variance")  # a wave's fields left out of design.json (waves.json keeps them)
# A refocused emulator needs this many runs per dimension of (x, theta) inside the earlier NROY, else it is
# fitted on every run: the 10 d of Loeppky, Sacks & Welch (2009, "Choosing the sample size of a computer
# experiment: a practical guide", Technometrics 51). On the pin fin, one refocused on 26 runs in 7 dimensions
# passed its checks (emulator_checks) and still ruled out the true theta (docs/design.md).
RUNS_PER_DIMENSION = 10


@dataclass
class Wave:
    """One wave: its cut, and what it found."""

    number: int
    runs_total: int  # the runs the config held at this wave
    runs_used: int  # the runs its emulator was fitted on (those inside the earlier NROY; every run unless refocused)
    refocused: bool  # False: too few runs inside the earlier NROY, so all were used
    emulator: dict  # ScalarEmulator / BasisEmulator .to_dict()
    discrepancy_variance: float
    noise_variance: list[float]
    nth: int
    cutoff: float
    nroy_fraction: float = float("nan")
    nroy_fraction_cv: float = float("nan")
    levels: list[float] = field(default_factory=list)
    checks: list[dict] = field(default_factory=list)  # each GP's held-out errors and variance inflation

    def cut(self, targets: Targets) -> Cut:
        """The wave's cut, with its own variances on the current observations."""
        if len(self.noise_variance) != targets.count:
            raise DataError(f"wave {self.number} was matched to {len(self.noise_variance)} observations and the "
                            f"physical data now hold {targets.count}; use a new --out folder")
        own = replace(targets, noise_variance=np.asarray(self.noise_variance),
                      discrepancy_variance=self.discrepancy_variance)
        return Cut(emulator_from_dict(self.emulator), own, self.nth, self.cutoff)

    def to_dict(self) -> dict:
        return dict(self.__dict__)

    def summary(self) -> dict:
        """The wave without its emulator, for design.json."""
        return {k: v for k, v in self.__dict__.items() if k not in BULKY}


@dataclass
class HistoryMatch:
    """Every wave so far, their cuts and a uniform sample of NROY."""

    data: object
    box: UnitBox
    targets: Targets
    waves: list[Wave]
    cuts: list[Cut]
    nroy: NroySample

    @property
    def nroy_fraction(self) -> float:
        return self.nroy.fraction

    @property
    def cutoff(self) -> float:
        return self.cuts[-1].cutoff

    def nroy_frame(self) -> pd.DataFrame:
        """The NROY sample, theta in original units (nroy.csv; with
        per-experiment theta, each experiment's own as ``name[experiment]``)."""
        return pd.DataFrame(self.box.theta_to_original(self.nroy.theta_unit), columns=self.box.nroy_names)

    def implausibility(self, theta: pd.DataFrame) -> np.ndarray:
        """Every wave's cut at theta (original units, nroy.csv's columns), as one implausibility."""
        return combined(self.cuts, self.box.theta_to_unit(theta[self.box.nroy_names].to_numpy(float)))

    def implausibility_at_runs(self, runs: pd.DataFrame) -> np.ndarray:
        """Every wave's cut at runs' theta (Cut.at_runs): the same as
        ``implausibility`` without per-experiment theta."""
        D = len(self.box.inputs)
        return combined(self.cuts, self.box.to_unit(runs)[:, D:], at_runs=True)

    def to_json(self) -> dict:
        return {"nroy_fraction": self.nroy_fraction, "nroy_fraction_cv": self.nroy.fraction_cv,
                "cutoff": self.cutoff, "runs": run_count(self.data), "nth_maximum": self.cuts[-1].nth,
                **self.targets.summary(), "box": self.box.to_dict(),
                "waves": [w.summary() for w in self.waves]}


def run_count(data) -> int:
    if not data.has_runs:
        raise DataError("stancal design needs simulator runs ([simulator] runs)")
    return len(data.run_settings) if isinstance(data, VectorCalibrationData) else len(data.runs)


def fit_emulator(data, xt: np.ndarray, outputs: np.ndarray, seed: int) -> ScalarEmulator | BasisEmulator:
    if isinstance(data, VectorCalibrationData):
        return BasisEmulator.fit(data.basis, xt, outputs, seed)
    return ScalarEmulator.fit(xt, outputs, seed)


def least_squares_variance(emulator, targets: Targets, dimensions: int, seed: int) -> float:
    """n / (n - Q) times the mean squared residual of the emulator mean at
    theta's least-squares fit: the best of a uniform sample of theta,
    polished by L-BFGS within the box. A censored value's residual is its
    mean's distance beyond its bounds; n counts the observed values."""
    from scipy import optimize

    def squares(theta: np.ndarray) -> np.ndarray:
        return np.sum(targets.distance(targets.emulate(emulator, theta)[0]) ** 2, axis=1)

    start = np.random.default_rng(seed).uniform(size=(2000, dimensions))
    best = start[np.argmin(squares(start))]
    found = optimize.minimize(lambda t: float(squares(t)[0]), best, method="L-BFGS-B", bounds=[(0, 1)] * dimensions)
    return float(found.fun) / max(int(targets.observed.sum()) - dimensions, 1)


def history_match(data, *, waves: list[Wave] | None = None, settings: DesignSettings | None = None,
                  seed: int = 1) -> HistoryMatch:
    """The next wave of history matching on ``data`` (a CalibrationData or
    VectorCalibrationData with runs), after the earlier ``waves`` (a
    HistoryMatch's, or waves.json's: load_waves; design.json's lack the
    emulators). When the runs are those of the last
    wave (nothing was appended since), that wave is redone instead."""
    settings = settings or DesignSettings()
    total = run_count(data)
    box = UnitBox.of(data)
    targets = targets_of(data, settings, box)
    earlier = list(waves or [])
    if earlier and earlier[-1].runs_total == total:  # no runs appended since: redo that wave
        earlier = earlier[:-1]
    xt, outputs = run_table(data, box)
    used, refocused = np.arange(total), False
    previous: list[Cut] = []  # earlier waves' cuts, built once (each rebuilds its emulator's factor)
    if earlier:
        previous = [w.cut(targets) for w in earlier]
        inside = np.flatnonzero(combined(previous, xt[:, len(box.inputs):], at_runs=True) <= previous[-1].cutoff)
        refocused = len(inside) >= RUNS_PER_DIMENSION * xt.shape[1]
        used = inside if refocused else used
        if not refocused:
            logger.warning("design: only %d runs lie inside the earlier waves' NROY (fewer than %d): wave %d's "
                           "emulator is fitted on all %d runs", len(inside), RUNS_PER_DIMENSION * xt.shape[1],
                           len(earlier) + 1, total)
    emulator, checks = checked(fit_emulator(data, xt[used], outputs[used], seed), seed)
    if max(c["inflation"] for c in checks) > 1:
        logger.info("design: wave %d's emulator is overconfident at runs it did not see; its variance is "
                    "inflated by %s", len(earlier) + 1, ", ".join(f"{c['inflation']:.2f}" for c in checks))
    if targets.noise_estimated:
        targets = targets.noise_bounded_by(least_squares_variance(emulator, targets, len(box.nroy_names), seed))
    nth = settings.nth_maximum or nth_maximum_for(targets.count, settings.cutoff)
    wave = Wave(len(earlier) + 1, total, len(used), refocused, emulator.to_dict(), targets.discrepancy_variance,
                targets.noise_variance.tolist(), nth, settings.cutoff, checks=checks)
    cuts = [*previous, wave.cut(targets)]
    nroy = sample_nroy(lambda t: combined(cuts, t), len(box.nroy_names), settings.cutoff, settings.nroy_points, seed)
    wave.nroy_fraction, wave.nroy_fraction_cv, wave.levels = nroy.fraction, nroy.fraction_cv, nroy.levels
    logger.info("design: wave %d, emulator on %d of %d runs; NROY %.3g of theta's box", wave.number,
                len(used), total, nroy.fraction)
    return HistoryMatch(data, box, targets, [*earlier, wave], cuts, nroy)


def load_waves(folder, data) -> list[Wave]:
    """The waves a design folder's waves.json holds ([] without one); they
    must be of the same problem (theta's bounds and the inputs' range)."""
    import json
    from pathlib import Path

    path = Path(folder) / "waves.json"
    if not path.is_file():
        return []
    stored = json.loads(path.read_text())
    box, now = stored["box"], UnitBox.of(data)
    same = (box["inputs"] == now.inputs and box["theta"] == now.theta and len(box["low"]) == len(now.low)
            and np.allclose(box["low"], now.low) and np.allclose(box["width"], now.width)
            and box.get("experiments", []) == now.experiments)
    if not same:
        raise DataError(f"{path} holds the waves of another problem (its theta, their bounds or the physical "
                        f"inputs' range differ from the config's); use a new --out folder")
    return [Wave(**w) for w in stored["waves"]]
