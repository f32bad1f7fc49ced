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

Every likelihood and censoring stancal calibrates with is matched:

- **Counts** (poisson, negbinomial, binomial) are matched on the link scale,
  where the latent programs put the emulator and add the discrepancy
  (functions/observation_model.stan: eta = g(f) + delta, g = log or logit):
  z = the empirical log, log(y + 1/2), or the empirical logit,
  log((y + 1/2) / (n - y + 1/2)), and the count model's variance by the
  delta method at the observed count, 1 / (y + 1/2) (+ 1 / (n - y + 1/2) for
  the logit) (Cox 1970, "The Analysis of Binary Data", section 3.2; Gart &
  Zweifel 1967, "On the bias of various estimators of the logit and its
  variance", Biometrika 54: the 1/2 keeps a zero count finite and makes the
  variance estimate nearly unbiased; the log is the logit's limit as n grows).
  A negative binomial adds its overdispersion 1 / phi on the log scale:
  ``[design] noise_sd`` squared when given (1 / sqrt(phi)), else estimated
  as the Gaussian noise is, less the count part (at least 0). For poisson
  and binomial the count model fixes the noise; ``[design] noise_sd`` adds
  to it when given.
- **Censored rows** (a Gaussian output with lower/upper bounds) give a
  one-sided implausibility: a row known only to lie in [l, u] (l = -inf or
  u = +inf when open) is implausible only when the emulator's mean lies
  beyond a bound, on the wrong side, by more than the cutoff's sds:
  max(l - E[f], E[f] - u, 0) / sd (as the censored likelihood's tail in
  observation_model.stan; an observed row is l = u = z, |z - E[f]| / sd).
  The noise estimates and the discrepancy's default use the observed rows.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from stancal.numerics.parametrization import model_scale_values
from stancal.problem.codes import Likelihood
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
        # imported here: `python -m stancal.problem.config_schema` (docs/config.md) must not find it imported
        # already by `import stancal`, which imports this module
        from stancal.problem.config_schema import table as config_table

        design = config_table("design")  # the ranges the config's [design] keys are checked against
        for name, value in asdict(self).items():
            key = design.key(name)
            problem = None if value is None else key.out_of_range(value) or (
                "must be an integer" if key.type == "integer" and not float(value).is_integer() else None)
            if problem:
                raise ValueError(f"[design] {name} {problem}; got {value!r}")


@dataclass
class Targets:
    """The observations and their variances, one entry per observed value,
    on the scale the emulator works on (output units, or a count's link
    scale). ``groups`` (vector outputs): per experiment, its inputs' row and
    the slice of values it holds, with their output indices; ``group_theta``
    (with per-experiment theta): per experiment, the columns of theta's
    NROY space that make its runs' theta (UnitBox.selection)."""

    x_unit: np.ndarray  # (n, D): each value's simulator inputs on the unit cube
    z: np.ndarray  # (n,): the observed values (NaN where censored)
    noise_variance: np.ndarray  # (n,)
    discrepancy_variance: float
    noise_source: str  # how the noise variance was found, in words
    discrepancy_source: str
    groups: list[tuple[np.ndarray, slice, np.ndarray]] = field(default_factory=list)
    lower: np.ndarray | None = None  # (n,): where each value is known to lie, [lower, upper]; z at both for
    upper: np.ndarray | None = None  # an observed value (the default), a bound open at -inf / +inf
    model_variance: np.ndarray | None = None  # (n,): the count model's part of noise_variance (0 for gaussian)
    group_theta: list[np.ndarray] = field(default_factory=list)
    noise_estimated: bool = False  # True: the noise variance was estimated (Rice's), so noise_bounded_by may lower it

    def __post_init__(self) -> None:
        self.lower = self.z if self.lower is None else self.lower
        self.upper = self.z if self.upper is None else self.upper
        self.model_variance = np.zeros(len(self.z)) if self.model_variance is None else self.model_variance

    @property
    def count(self) -> int:
        return len(self.z)

    @property
    def observed(self) -> np.ndarray:
        return ~np.isnan(self.z)

    def distance(self, mean: np.ndarray) -> np.ndarray:
        """How far each mean (S, n) lies outside where its value is known to
        lie: |z - mean| for an observed value; beyond the bound, on the
        wrong side, for a censored one (0 inside its range)."""
        return np.maximum(np.maximum(self.lower - mean, mean - self.upper), 0.0)

    def standardised(self, mean: np.ndarray, variance: np.ndarray) -> np.ndarray:
        """I_i: each distance (S, n) over the sd of the emulator's error
        (``variance``, S x n) plus the discrepancy's and the noise's."""
        return self.distance(mean) / np.sqrt(variance + self.discrepancy_variance + self.noise_variance)

    def emulate(self, emulator, theta_unit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The emulator's mean and variance (S, n) at each value, for S points
        of theta's NROY space (each experiment's own theta taken out of it)."""
        return self.emulate_at(emulator, self.x_unit, theta_unit)

    def emulate_at(self, emulator, x_unit: np.ndarray, theta_unit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The same at the values' inputs ``x_unit`` (all of them, or a
        scalar output's chosen rows; a vector output's are its groups')."""
        theta_unit = np.atleast_2d(theta_unit)
        by_group = [theta_unit[:, columns] for columns in self.group_theta] or None
        return emulator.at(x_unit, theta_unit, self.groups, by_group)

    def noise_bounded_by(self, residual_variance: float) -> Targets:
        """The estimated noise variance, or ``residual_variance`` (the
        least-squares fit's) when smaller: all of it for a Gaussian output,
        the part beyond the count model's (at least 0) for counts."""
        extra = float(np.mean(self.noise_variance - self.model_variance))
        bound = max(residual_variance - float(np.mean(self.model_variance)), 0.0)
        if not self.noise_estimated or bound >= extra:
            return self
        return replace(self, noise_variance=self.model_variance + bound,
                       noise_source="estimated as the residual variance of the emulator's least-squares fit of theta"
                       + (" less the count model's" if self.model_variance.any() else ""))

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
        values = {"groups": groups, "group_theta": box.selections()}
        model, fixed = np.zeros(len(z)), None
    else:
        x_unit, z, values, model, fixed, neighbour = _scalar_values(data, box)
        known = None
    observed, estimated = ~np.isnan(z), False
    if settings.noise_sd is not None:
        extra, noise_source = settings.noise_sd**2, "[design] noise_sd" + (f", added to {fixed}" if fixed else "")
    elif known is not None:
        extra, noise_source = known**2, "the physical data's known noise sd column"
    elif fixed:
        extra, noise_source = 0.0, fixed
    else:
        extra, estimated = max(rice_variance(z[observed], neighbour) - float(np.mean(model[observed])), 0.0), True
        noise_source = "estimated from neighbouring observations' differences (Rice 1984)" + (
            ", less the count model's" if model.any() else "")
    if settings.discrepancy_sd is not None:
        discrepancy, discrepancy_source = settings.discrepancy_sd**2, "[design] discrepancy_sd"
    else:
        discrepancy = (settings.discrepancy_fraction * float(np.std(z[observed]))) ** 2
        discrepancy_source = f"{settings.discrepancy_fraction:g} x the observations' sd ([design] discrepancy_fraction)"
    if model.any():  # counts: every variance is on the link scale
        discrepancy_source += ", on the link scale"
    return Targets(x_unit, z, model + extra, discrepancy, noise_source, discrepancy_source, model_variance=model,
                   noise_estimated=estimated, **values)


def _scalar_values(data, box: UnitBox):
    """A scalar output's values on the emulator's scale: z (NaN where
    censored), their bounds, the count model's variance (module docstring),
    what fixes the noise (the count model's words; None: to be estimated),
    and each observed value's nearest observed neighbour in the inputs."""
    observations = data.observations
    y, kind = observations.value, observations.likelihood
    bounds: dict = {}
    if kind is Likelihood.BINOMIAL:  # the empirical logit, where the latent programs' normal approximation sits
        z, model = model_scale_values(observations, y), 1 / (y + 0.5) + 1 / (observations.trials - y + 0.5)
    elif kind in (Likelihood.POISSON, Likelihood.NEGBINOMIAL):  # log(y + 1/2)
        z, model = model_scale_values(observations, y), 1 / (y + 0.5)
    else:
        observed = observations.observed
        z, model = np.where(observed, y, np.nan), np.zeros(len(y))
        bounds = {"lower": np.where(observed, y, observations.lower),
                  "upper": np.where(observed, y, observations.upper)}
    fixed = None
    if kind in (Likelihood.POISSON, Likelihood.BINOMIAL):
        fixed = (f"the {kind.name.lower()} model's variance on the link scale (delta method at the observed "
                 f"count, Cox 1970)")
    x_unit = box.inputs_to_unit(data.physical)
    x_observed = x_unit[~np.isnan(z)]
    neighbour = cKDTree(x_observed).query(x_observed, k=2)[1][:, 1]
    return x_unit, z, bounds, model, fixed, neighbour


def _vector_values(data: VectorCalibrationData, box: UnitBox):
    """A vector output's values experiment by experiment (in the order of
    data.experiments), each sorted along its first output index; a value's
    neighbour is the next one along the index within its experiment."""
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
    runs outside it lie outside [0, 1], which a GP takes), theta over its bounds.

    ``theta`` are the runs' theta columns: the shared theta, then the
    per-experiment ones (``per_experiment``, a vector output's
    [simulator.theta_per_experiment]). NROY lives in the space calibration
    samples: the shared theta, then each per-experiment theta once per
    experiment (``nroy_names``: ``name[experiment]``); experiment e's
    values are emulated at the shared theta and its own (``selection``)."""

    inputs: list[str]
    theta: list[str]
    low: np.ndarray  # inputs, then theta
    width: np.ndarray
    experiments: list[str] = field(default_factory=list)  # with per-experiment theta only
    per_experiment: list[str] = field(default_factory=list)

    @classmethod
    def of(cls, data) -> UnitBox:
        vector = isinstance(data, VectorCalibrationData)
        settings = data.experiments if vector else data.physical
        parameters = data.all_parameters if vector else data.parameters
        low = [float(settings[c].min()) for c in data.inputs] + [p.lower for p in parameters]
        width = ([float(np.ptp(settings[c].to_numpy(float))) or 1.0 for c in data.inputs]
                 + [p.upper - p.lower for p in parameters])
        per_experiment = [p.name for p in data.per_experiment] if vector else []
        experiments = [str(e) for e in data.experiments.index] if per_experiment else []
        return cls(list(data.inputs), [p.name for p in parameters], np.array(low), np.array(width), experiments,
                   per_experiment)

    @property
    def columns(self) -> list[str]:
        return [*self.inputs, *self.theta]

    @property
    def shared(self) -> int:
        return len(self.theta) - len(self.per_experiment)

    @property
    def nroy_names(self) -> list[str]:
        """NROY's theta: the runs' theta, or with per-experiment theta the
        shared ones and then each experiment's own."""
        own = [f"{name}[{e}]" for e in self.experiments for name in self.per_experiment]
        return [*self.theta[:self.shared], *own]

    def selection(self, experiment: int) -> np.ndarray:
        """The columns of NROY's theta that make experiment ``experiment``'s runs' theta."""
        own = self.shared + experiment * len(self.per_experiment) + np.arange(len(self.per_experiment))
        return np.concatenate([np.arange(self.shared), own]).astype(int)

    def selections(self) -> list[np.ndarray]:
        """Every experiment's selection ([] without per-experiment theta)."""
        return [self.selection(e) for e in range(len(self.experiments))]

    def run_theta(self, nroy_unit: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Runs' theta (rows, Q) from NROY points: each point's own with
        shared theta only, else its shared theta and a random experiment's own."""
        if not self.per_experiment:
            return nroy_unit
        chosen = rng.integers(0, len(self.experiments), len(nroy_unit))
        columns = np.array(self.selections())[chosen]
        return np.take_along_axis(nroy_unit, columns, axis=1)

    def nroy_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """NROY's theta's low ends and widths (nroy_names' order)."""
        D = len(self.inputs)
        # each experiment's own theta has its name's bounds
        own = np.tile(self.shared + np.arange(len(self.per_experiment)), len(self.experiments))
        columns = np.concatenate([np.arange(self.shared), own]).astype(int)
        return self.low[D:][columns], self.width[D:][columns]

    def to_unit(self, frame) -> np.ndarray:
        """(rows, D + Q) of a frame with the inputs and theta."""
        return (frame[self.columns].to_numpy(float).reshape(len(frame), -1) - self.low) / self.width

    def inputs_to_unit(self, frame) -> np.ndarray:
        """(rows, D) of a frame with the inputs (D = 0 allowed)."""
        D = len(self.inputs)
        return (frame[self.inputs].to_numpy(float).reshape(len(frame), D) - self.low[:D]) / self.width[:D]

    def theta_to_unit(self, values: np.ndarray) -> np.ndarray:
        """(rows, Q) of NROY's theta (nroy_names) in original units, on the unit cube."""
        low, width = self.nroy_bounds()
        return (np.asarray(values, float) - low) / width

    def inputs_to_original(self, unit: np.ndarray) -> np.ndarray:
        D = len(self.inputs)
        return self.low[:D] + unit * self.width[:D]

    def theta_to_original(self, unit: np.ndarray) -> np.ndarray:
        """NROY's theta (nroy_names) in original units."""
        low, width = self.nroy_bounds()
        return low + unit * width

    def to_original(self, unit: np.ndarray) -> np.ndarray:
        return self.low + unit * self.width

    def to_dict(self) -> dict:
        return {"inputs": self.inputs, "theta": self.theta, "low": self.low.tolist(), "width": self.width.tolist(),
                **({"experiments": self.experiments, "per_experiment": self.per_experiment}
                   if self.per_experiment else {})}


def run_table(data, box: UnitBox) -> tuple[np.ndarray, np.ndarray]:
    """Every run's (x, theta) on the unit cube and its output (runs,) or
    (runs, K): a scalar output's on its likelihood's link scale, where the
    emulator works (the latent programs' stage 1 does so too)."""
    if isinstance(data, VectorCalibrationData):
        return box.to_unit(data.run_settings), data.run_outputs
    return box.to_unit(data.runs), data.runs_on_link_scale()
