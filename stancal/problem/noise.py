"""The measurement noise of a scalar output (docs/noise.md;
stan_models/functions/noise.stan): each row's known measurement sd (a
``noise_sd`` column), its measurement source (a ``source`` column), and the
noise model over them, ``noise``: iid (one estimated sd), per_source (one
per source), student_t (Student-t with estimated degrees of freedom) or
heteroscedastic (a log sd that is a GP over the inputs, Binois, Gramacy &
Ludkovski 2018; Sung, Barber & Walker 2022: stancal.numerics.noise_gp). A
known sd adds in quadrature to the estimated one (Hogg, Bovy & Lang 2010,
section 7). The same arithmetic serves new observations and held-out
scores, so that predictions and `stancal gap` use the fit's own noise."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from stancal.problem.advice import config_key
from stancal.problem.codes import Noise
from stancal.problem.run_replicates import group_settings
from stancal.problem.validation import DataError, numeric_values, row_labels

NOISES = tuple(code.name.lower() for code in Noise)  # iid, per_source, student_t, heteroscedastic
HETEROSCEDASTIC = Noise.HETEROSCEDASTIC.name.lower()
PER_SOURCE = Noise.PER_SOURCE.name.lower()
# a row whose posterior mean Student-t weight is below this counts at most a
# quarter as much as a row of the prior mean weight, 1: the report lists it as an
# outlier. Without a GP that is a residual beyond sqrt(3 nu + 4) scales: 3.6 at
# nu = 3, 8 at nu = 20 (E(w | resid), Lange, Little & Taylor 1989)
OUTLIER_WEIGHT = 0.25


@dataclass(frozen=True)
class MeasurementNoise:
    """The rows' known sds and sources, as the physical data give them."""

    noise_sd_column: str | None
    source_column: str | None
    known_sd: np.ndarray  # per row, output units; 0 where no column
    sources: tuple[str, ...]  # the distinct sources, sorted (one named "all" without a column)
    source_index: np.ndarray  # per row, 0-based into sources

    @property
    def rows_per_source(self) -> np.ndarray:
        """How many physical rows each source has (in the order of ``sources``)."""
        return np.bincount(self.source_index, minlength=len(self.sources))

    @property
    def given_sources(self) -> list[str] | None:
        """The sources as a rebuilt or reloaded problem must keep them (None
        without a source column: there is no column to read them from)."""
        return list(self.sources) if self.source_column else None

    def at(self, points: pd.DataFrame, what: str = "prediction points") -> tuple[np.ndarray | None, np.ndarray]:
        """The sources (None where the points have no source column) and known
        sds (0 where they have no noise_sd column) of new points, read as the
        physical data are, against the physical data's sources."""
        sd_column = self.noise_sd_column if self.noise_sd_column and self.noise_sd_column in points else None
        source_column = self.source_column if self.source_column and self.source_column in points else None
        read = read_measurement_noise(points, sd_column, source_column, what,
                                      self.sources if source_column else None)
        return (read.source_index if source_column else None), read.known_sd


def positive_sd(frame: pd.DataFrame, column: str, what: str) -> np.ndarray:
    """A known-sd column: finite and positive, or a DataError naming the rows."""
    values = numeric_values(frame, column, what)
    bad = ~(np.isfinite(values) & (values > 0))
    if bad.any():
        raise DataError(f"{what}: column '{column}' (known noise sd) must be positive and finite; "
                        f"{row_labels(bad, frame.index)} hold {values[bad][:5].tolist()}")
    return values


def source_names(frame: pd.DataFrame, column: str, what: str) -> list[str]:
    """A source column as text, or a DataError naming the empty rows."""
    values = frame[column]
    bad = values.isna().to_numpy() | (values.astype(str).str.strip() == "").to_numpy()
    if bad.any():
        raise DataError(f"{what}: column '{column}' (measurement source) is empty in "
                        f"{row_labels(bad, frame.index)}")
    return [str(v) for v in values]


def read_measurement_noise(frame: pd.DataFrame, noise_sd: str | None, source: str | None, what: str,
                           sources: Sequence[str] | None = None) -> MeasurementNoise:
    """The rows' known sds and sources from the physical data, checked;
    ``sources``: the distinct sources when a subset of rows must keep its
    parent's (each source's sd keeps its index)."""
    for key, column in (("noise_sd", noise_sd), ("source", source)):
        if column and column not in frame.columns:
            raise DataError(f"{what}: no column '{column}' (the {key} column, [physical] {key}); "
                            f"available: {list(frame.columns)}")
    known = positive_sd(frame, noise_sd, what) if noise_sd else np.zeros(len(frame))
    if not source:
        return MeasurementNoise(noise_sd, None, known, ("all",), np.zeros(len(frame), dtype=int))
    names = source_names(frame, source, what)
    sources = tuple(sources) if sources is not None else tuple(sorted(set(names)))
    unknown = sorted(set(names) - set(sources))
    if unknown:
        raise DataError(f"{what}: column '{source}' names source(s) {unknown} that the physical data lack; "
                        f"known: {list(sources)}")
    return MeasurementNoise(noise_sd, source, known, sources, np.array([sources.index(n) for n in names]))


def check_noise_name(noise: str) -> None:
    """A noise model stancal has."""
    if noise not in NOISES:
        raise ValueError(f"noise must be one of {', '.join(NOISES)}; got {noise!r}")


def check_noise(noise: str, measurement: MeasurementNoise, biased_sources: Sequence[str] = ()) -> None:
    """The noise model against the data's columns, before anything compiles;
    the message names the key to change. The name itself is checked where
    it is read (ModelOptions, the config), so it is a name stancal has. A
    source column serves per-source noise or biased sources
    (stancal.problem.source_bias)."""
    column = measurement.source_column
    if noise == "per_source" and column is None:
        raise DataError(f"{config_key('model', 'noise', noise)} needs each row's measurement source: name its "
                        "column as [physical] source (CalibrationData's source=)")
    if noise == "per_source" and len(measurement.sources) < 2:
        raise DataError(f"{config_key('model', 'noise', noise)}: column '{column}' names one source only "
                        f"({measurement.sources[0]!r}); one sd per source needs two or more, else use noise = \"iid\"")
    if column is not None and noise != "per_source" and not biased_sources:
        raise DataError(f"the physical data name a measurement source (column '{column}'), which only "
                        f"noise = \"per_source\" uses (or [model] biased_sources); set "
                        f"{config_key('model', 'noise', 'per_source')}, name [model] biased_sources, or "
                        "leave the source out")


def check_noise_inputs(noise: str, noise_inputs: Sequence[str], inputs: Sequence[str] | None = None) -> None:
    """[model] noise_inputs: given with heteroscedastic noise only, and (with
    ``inputs``, the simulator inputs) each a simulator input."""
    if noise_inputs and noise != HETEROSCEDASTIC:
        raise ValueError(f"{config_key('model', 'noise_inputs', list(noise_inputs))} applies to "
                         f"noise = \"{HETEROSCEDASTIC}\" only; got noise = {noise!r}")
    unknown = [name for name in noise_inputs if inputs is not None and name not in inputs]
    if unknown:
        raise ValueError(f"{config_key('model', 'noise_inputs', list(noise_inputs))}: {unknown} are not "
                         f"simulator inputs; choose among {list(inputs)}")


def noise_input_names(options, data) -> list[str]:
    """The inputs heteroscedastic noise varies over: [model] noise_inputs, by default every simulator input."""
    return list(options.noise_inputs or data.inputs)


def describes_noise(options, data) -> bool:
    """Whether the fit models its measurements beyond one iid sd (another
    noise model, a known sd column or biased sources): summary.json then has
    a noise block, and the report its section."""
    return options.noise != "iid" or bool(data.noise.noise_sd_column) or bool(options.biased_sources)


# the log sd GP's length-scale prior's smallest lognormal scale: 95 % within a factor of 2 of its median
LENGTH_SCALE_FLOOR = float(np.log(2) / 1.959964)


@dataclass(frozen=True)
class NoiseLocations:
    """Heteroscedastic noise: the distinct settings of the noise inputs,
    where its log sd GP lives (replicated rows share one), on the unit scale."""

    inputs: tuple[str, ...]
    unit: np.ndarray  # (locations, inputs), each input scaled to [0, 1]
    row_location: np.ndarray  # per row, 0-based into unit

    @classmethod
    def of(cls, unit_values: np.ndarray, inputs: Sequence[str]) -> NoiseLocations:
        distinct, index, _ = group_settings(unit_values)
        return cls(tuple(inputs), distinct, index)

    def length_scale_prior(self) -> tuple[float, float]:
        """The lognormal (location, scale) of the log sd GP's length scales
        (unit scale): 95 % of its mass between the finest input's spacing
        and its range, both measured on the settings (runs may stretch the
        unit scale beyond them): a GP no shorter than the spacing of the
        settings it is seen at. With four values or fewer (range < 4
        spacings) the scale is LENGTH_SCALE_FLOOR, 95 % within a factor of 2
        of the geometric mean of spacing and range (two values: their distance)."""
        counts = [len(np.unique(self.unit[:, j])) for j in range(self.unit.shape[1])]
        finest = int(np.argmax(counts))
        span = float(np.ptp(self.unit[:, finest]))
        spacing = span / (counts[finest] - 1)
        return 0.5 * np.log(spacing * span), max(np.log(span / spacing) / (2 * 1.959964), LENGTH_SCALE_FLOOR)

    def stan_data(self) -> dict:
        """functions/noise.stan's heteroscedastic data."""
        return {"N_loc": len(self.unit), "D_noise": self.unit.shape[1], "x_noise": self.unit,
                "noise_loc": self.row_location + 1,
                "noise_length_scale_prior": [float(v) for v in self.length_scale_prior()]}


# the Stan data of a homoscedastic noise: no locations
NO_LOCATIONS = {"N_loc": 0, "D_noise": 0, "x_noise": np.zeros((0, 0)), "noise_loc": np.zeros(0, dtype=int),
                "noise_length_scale_prior": [0.0, 1.0]}


def check_noise_locations(locations: NoiseLocations) -> None:
    """Heteroscedastic noise needs each noise input to vary: a GP over one value is only a level."""
    flat = [name for j, name in enumerate(locations.inputs) if len(np.unique(locations.unit[:, j])) < 2]
    if flat:
        raise DataError(f"{config_key('model', 'noise', HETEROSCEDASTIC)}: the noise inputs {flat} take one value "
                        "in the physical data; the noise sd cannot vary over them: set [model] noise_inputs to "
                        "inputs that vary, or use noise = \"iid\"")


def noise_locations(data, options) -> NoiseLocations | None:
    """Heteroscedastic noise: the distinct settings of its inputs (by default
    every simulator input) among ``data``'s physical rows (a CalibrationData),
    checked; else None. The plan calls it before anything compiles."""
    if options.noise != HETEROSCEDASTIC:
        return None
    inputs = noise_input_names(options, data)
    locations = NoiseLocations.of(data.scaling.to_unit(data.physical, inputs), inputs)
    check_noise_locations(locations)
    return locations


def replicate_counts(inputs: np.ndarray) -> dict[str, int]:
    """Replicates: rows whose inputs equal another row's, found by exact
    equality. ``settings``: distinct input settings; ``replicated_settings``:
    those measured more than once; ``replicate_rows``: the rows beyond each
    setting's first (rows - settings)."""
    _, _, counts = group_settings(inputs)
    return {"rows": int(counts.sum()), "settings": len(counts), "replicated_settings": int((counts > 1).sum()),
            "replicate_rows": int(counts.sum() - len(counts))}


def stan_noise_data(noise: str, measurement: MeasurementNoise, y_scale: float) -> dict:
    """functions/noise.stan's data: the model's code, the sds' count, each
    row's sd (1-based) and known sd on the standardised scale."""
    per_source = noise == "per_source"
    return {"noise_id": int(Noise[noise.upper()]), "S": len(measurement.sources) if per_source else 1,
            "source": (measurement.source_index + 1) if per_source else np.ones(len(measurement.known_sd), int),
            "known_sd": measurement.known_sd / y_scale}


def with_known_sd(sd: np.ndarray, known_sd: np.ndarray) -> np.ndarray:
    """An estimated noise sd and a known one in quadrature (noise.stan's noise_variance)."""
    return np.sqrt(sd**2 + known_sd**2)


def row_noise_sd(noise_sd: np.ndarray, source_index: np.ndarray | None, known_sd: np.ndarray,
                 shares: Sequence[float] = (), rng: np.random.Generator | None = None) -> np.ndarray:
    """Each draw's noise scale at each row, (draws, rows): sqrt(sigma[source]^2
    + known^2) from the estimated sds (draws, sources) (noise.stan's
    noise_variance). Rows of no known source (``source_index`` None) take a
    source at random per draw, in the ``shares`` of the physical rows: a new
    measurement by one of the instruments the data came from."""
    sigma = noise_sd.reshape(len(noise_sd), -1)
    if source_index is None:
        if sigma.shape[1] == 1:
            source_index = np.zeros(len(known_sd), dtype=int)
        else:
            assert rng is not None, "drawing the sources of new points needs a generator"
            chosen = rng.choice(sigma.shape[1], size=(len(sigma), len(known_sd)), p=np.asarray(shares))
            return with_known_sd(np.take_along_axis(sigma, chosen, axis=1), known_sd)
    return with_known_sd(sigma[:, source_index], known_sd)


def draw_noise(rng: np.random.Generator, scale: np.ndarray, nu: np.ndarray | None) -> np.ndarray:
    """Noise of the given scale (draws, rows): normal, or Student-t with each draw's nu."""
    if nu is None:
        return scale * rng.standard_normal(scale.shape)
    return scale * rng.standard_t(np.asarray(nu).reshape(-1, 1), size=scale.shape)


def outlier_rows(weights: np.ndarray, threshold: float = OUTLIER_WEIGHT) -> pd.DataFrame:
    """The rows a Student-t fit discounts (West 1984): posterior mean weight
    below ``threshold`` (prior mean 1), from draws (draws, rows); with each
    row's mean weight, lowest first."""
    mean = np.asarray(weights).reshape(-1, np.shape(weights)[-1]).mean(axis=0)
    rows = np.flatnonzero(mean < threshold)
    return pd.DataFrame({"row": rows, "weight": mean[rows]}).sort_values("weight").reset_index(drop=True)
