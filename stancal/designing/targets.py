"""What history matching compares the emulator with: the observations z, the
physical points they were taken at, and the two variances the emulator's
error is added to, the measurement's and the model discrepancy's (Craig et
al. 1996, "Bayes linear strategies for matching hydrocarbon reservoir
history"; Vernon et al. 2010, "Galaxy formation: a Bayesian uncertainty
analysis", Bayesian Analysis 5, section 3).

- The discrepancy sd is ``[design] discrepancy_sd`` (output units) when
  given, else ``discrepancy_fraction`` (default DISCREPANCY_FRACTION) of the
  observations' sd over the physical points (docs/design.md says why).
- The noise sd is the known one (a vector output's ``noise_sd`` column, or
  ``[design] noise_sd``), else the smaller of two estimates that each err
  on the wide side (the side that rules out less): the difference estimate
  of Rice (1984, "Bandwidth choice for nonparametric regression", Ann.
  Statist. 12), half the mean squared difference of neighbouring
  observations, which adds the process's change between neighbours; and
  the residual variance of the emulator mean at theta's least-squares fit
  (n / (n - Q) times the mean square), which adds the discrepancy.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from stancal.problem.validation import DataError
from stancal.problem.vector_data import VectorCalibrationData

DISCREPANCY_FRACTION = 0.1  # of the observations' sd: docs/design.md, "The discrepancy's default"
CUTOFF = 3.0  # Pukelsheim (1994): 95 % of any unimodal distribution lies within 3 sd


@dataclass(frozen=True)
class DesignSettings:
    """The [design] table of a config (docs/config.md). Each key's default
    lives here; stancal.problem.config_schema documents them."""

    discrepancy_sd: float | None = None  # output units; None: discrepancy_fraction of the observations' sd
    discrepancy_fraction: float = DISCREPANCY_FRACTION
    noise_sd: float | None = None  # output units; None: the known sd column, else the smaller of Rice's
    # estimate and the emulator's least-squares residual variance (Targets.noise_bounded_by)
    nth_maximum: int | None = None  # 1, 2 or 3; None: chosen from the number of observations
    cutoff: float = CUTOFF
    nroy_points: int = 2000  # NROY sample size (nroy.csv)

    def __post_init__(self) -> None:
        checks = [("discrepancy_sd", self.discrepancy_sd, lambda v: v is None or v >= 0, "at least 0"),
                  ("discrepancy_fraction", self.discrepancy_fraction, lambda v: v >= 0, "at least 0"),
                  ("noise_sd", self.noise_sd, lambda v: v is None or v > 0, "positive"),
                  ("nth_maximum", self.nth_maximum, lambda v: v in (None, 1, 2, 3), "1, 2 or 3"),
                  ("cutoff", self.cutoff, lambda v: v > 0, "positive"),
                  ("nroy_points", self.nroy_points, lambda v: v >= 1000, "at least 1000")]
        for name, value, ok, what in checks:
            if not ok(value):
                raise ValueError(f"[design] {name} must be {what}; got {value!r}")


@dataclass
class Targets:
    """The observations and their variances, one entry per observed value.
    ``groups`` (vector outputs): per experiment, its inputs' row and the
    slice of values it holds, with their output indices."""

    x_unit: np.ndarray  # (n, D): each value's simulator inputs on the unit cube
    z: np.ndarray  # (n,): the observed values, output units
    noise_variance: np.ndarray  # (n,)
    discrepancy_variance: float
    noise_source: str  # how the noise variance was found, in words
    discrepancy_source: str
    groups: list[tuple[np.ndarray, slice, np.ndarray]] = field(default_factory=list)

    @property
    def count(self) -> int:
        return len(self.z)

    @property
    def noise_estimated(self) -> bool:
        return self.noise_source.startswith("estimated")

    def noise_bounded_by(self, residual_variance: float) -> Targets:
        """The estimated noise variance, or ``residual_variance`` (the least-squares fit's) when smaller."""
        if not self.noise_estimated or residual_variance >= self.noise_variance[0]:
            return self
        return replace(self, noise_variance=np.full(self.count, residual_variance),
                       noise_source="estimated as the residual variance of the emulator's least-squares fit of theta")

    def summary(self) -> dict:
        return {"observations": self.count, "noise_sd": float(np.sqrt(np.mean(self.noise_variance))),
                "noise_sd_source": self.noise_source, "discrepancy_sd": float(np.sqrt(self.discrepancy_variance)),
                "discrepancy_sd_source": self.discrepancy_source}


def rice_variance(z: np.ndarray, neighbour: np.ndarray) -> float:
    """Half the mean squared difference between each value and its neighbour."""
    return float(np.mean((z - z[neighbour]) ** 2) / 2)


def targets_of(data, settings: DesignSettings, box: UnitBox | None = None) -> Targets:
    """The Targets of a scalar or vector calibration problem (``box``: the
    design's UnitBox, UnitBox.of(data) when not given)."""
    box = box or UnitBox.of(data)
    if isinstance(data, VectorCalibrationData):
        x_unit, z, groups, known, neighbour = _vector_values(data, box)
    else:
        if not data.observations.is_gaussian or not data.observations.observed.all():
            raise DataError("stancal design takes a gaussian output without censored rows ([model] likelihood, "
                            "lower, upper): implausibility compares the emulator with measured values")
        x_unit = box.inputs_to_unit(data.physical)
        z = data.physical[data.output].to_numpy(float)
        groups, known = [], None
        neighbour = cKDTree(x_unit).query(x_unit, k=2)[1][:, 1]
    if settings.noise_sd is not None:
        noise, noise_source = np.full(len(z), settings.noise_sd**2), "[design] noise_sd"
    elif known is not None:
        noise, noise_source = known**2, "the physical data's known noise sd column"
    else:
        noise = np.full(len(z), rice_variance(z, neighbour))
        noise_source = "estimated from neighbouring observations' differences (Rice 1984)"
    if settings.discrepancy_sd is not None:
        discrepancy, discrepancy_source = settings.discrepancy_sd**2, "[design] discrepancy_sd"
    else:
        discrepancy = (settings.discrepancy_fraction * float(np.std(z))) ** 2
        discrepancy_source = f"{settings.discrepancy_fraction:g} x the observations' sd ([design] discrepancy_fraction)"
    return Targets(x_unit, z, noise, discrepancy, noise_source, discrepancy_source, groups)


def _vector_values(data: VectorCalibrationData, box: UnitBox):
    """A vector output's values experiment by experiment (in the order of
    data.experiments), each sorted along its first output index; a value's
    neighbour is the next one along the index within its experiment."""
    if data.per_experiment:
        raise DataError("stancal design does not take [simulator.theta_per_experiment] yet: history matching "
                        "needs theta shared by every experiment")
    physical = data.physical
    x_rows = box.inputs_to_unit(data.experiments)
    x_parts, z_parts, known_parts, groups, neighbours, start = [], [], [], [], [], 0
    for row, name in zip(x_rows, data.experiments.index, strict=True):
        rows = physical[physical[data.experiment] == name].sort_values(data.output_index)
        m = len(rows)
        groups.append((row, slice(start, start + m), rows[data.output_index].to_numpy(float)))
        x_parts.append(np.repeat(row[None, :], m, axis=0))
        z_parts.append(rows[data.output].to_numpy(float))
        if data.noise_sd:
            known_parts.append(rows[data.noise_sd].to_numpy(float))
        neighbour = start + np.arange(1, m + 1) if m > 1 else np.array([start])
        if m > 1:
            neighbour[-1] = start + m - 2  # the last value's neighbour is the one before it
        neighbours.append(neighbour)
        start += m
    known = np.concatenate(known_parts) if data.noise_sd else None
    return (np.vstack(x_parts), np.concatenate(z_parts), groups, known, np.concatenate(neighbours))


@dataclass(frozen=True)
class UnitBox:
    """The unit cube the design works on: each simulator input over the
    physical data's range (fixed over the waves, as the physical data are;
    runs outside it lie outside [0, 1], which a GP takes), theta over its bounds."""

    inputs: list[str]
    theta: list[str]
    low: np.ndarray  # inputs, then theta
    width: np.ndarray

    @classmethod
    def of(cls, data) -> UnitBox:
        settings = data.experiments if isinstance(data, VectorCalibrationData) else data.physical
        low = [float(settings[c].min()) for c in data.inputs] + [p.lower for p in data.parameters]
        width = ([float(np.ptp(settings[c].to_numpy(float))) or 1.0 for c in data.inputs]
                 + [p.upper - p.lower for p in data.parameters])
        return cls(list(data.inputs), list(data.theta_names), np.array(low), np.array(width))

    @property
    def columns(self) -> list[str]:
        return [*self.inputs, *self.theta]

    def to_unit(self, frame) -> np.ndarray:
        """(rows, D + Q) of a frame with the inputs and theta."""
        return (frame[self.columns].to_numpy(float).reshape(len(frame), -1) - self.low) / self.width

    def inputs_to_unit(self, frame) -> np.ndarray:
        """(rows, D) of a frame with the inputs (D = 0 allowed)."""
        D = len(self.inputs)
        return (frame[self.inputs].to_numpy(float).reshape(len(frame), D) - self.low[:D]) / self.width[:D]

    def theta_to_unit(self, values: np.ndarray) -> np.ndarray:
        """(rows, Q) of theta in original units, on the unit cube."""
        D = len(self.inputs)
        return (np.asarray(values, float) - self.low[D:]) / self.width[D:]

    def inputs_to_original(self, unit: np.ndarray) -> np.ndarray:
        D = len(self.inputs)
        return self.low[:D] + unit * self.width[:D]

    def theta_to_original(self, unit: np.ndarray) -> np.ndarray:
        D = len(self.inputs)
        return self.low[D:] + unit * self.width[D:]

    def to_original(self, unit: np.ndarray) -> np.ndarray:
        return self.low + unit * self.width

    def to_dict(self) -> dict:
        return {"inputs": self.inputs, "theta": self.theta, "low": self.low.tolist(), "width": self.width.tolist()}
