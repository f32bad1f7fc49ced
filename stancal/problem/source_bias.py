"""Biased measurement sources (docs/noise.md; stan_models/functions/source_bias.stan):
``biased_sources`` names the sources of the ``source`` column whose readings
carry a bias of their own over the inputs, a GP b_s beside the shared
discrepancy delta: the measurement bias of Gu, Anderson & McPhillips (2023,
"Calibration of imperfect geophysical models by multiple satellite
interferograms with measurement bias", Technometrics 65), as the R package
RobustCalibration fits it for several sources of data (review section 8.1.3). The other
sources are references: they see delta alone, and so anchor its level. Here:
the rules checked before anything compiles, and each row's biased source as
the programs take it."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from stancal.problem.advice import config_key
from stancal.problem.noise import MeasurementNoise
from stancal.problem.validation import DataError

KEY = ("model", "biased_sources")


def check_biased_sources(biased_sources: Sequence[str], measurement: MeasurementNoise) -> None:
    """biased_sources against the data's source column: a column to read the
    sources from, names among its values, each once, and at least one reference
    source left; one-line DataErrors that name the key."""
    if not biased_sources:
        return
    key = config_key(*KEY, list(biased_sources))
    column = measurement.source_column
    if column is None:
        raise DataError(f"{key} needs each row's measurement source: name its column as [physical] source "
                        "(CalibrationData's source=)")
    repeated = sorted({name for name in biased_sources if list(biased_sources).count(name) > 1})
    if repeated:
        raise DataError(f"{key}: {repeated} named more than once")
    unknown = [name for name in biased_sources if name not in measurement.sources]
    if unknown:
        raise DataError(f"{key}: {unknown} are not sources in column '{column}'; its sources are "
                        f"{list(measurement.sources)}")
    if len(set(biased_sources)) == len(measurement.sources):
        raise DataError(f"{key}: every source of column '{column}' is biased, so none anchors the discrepancy's "
                        "level (a bias and the discrepancy would trade freely): leave at least one reference "
                        "source out of biased_sources")


def bias_index(biased_sources: Sequence[str], measurement: MeasurementNoise) -> np.ndarray:
    """Each row's biased source, 1-based in the order of ``biased_sources``;
    0 for a row read by a reference source."""
    number = {measurement.sources.index(name): b + 1 for b, name in enumerate(biased_sources)}
    return np.array([number.get(int(s), 0) for s in measurement.source_index], dtype=int)


def stan_bias_data(biased_sources: Sequence[str], measurement: MeasurementNoise) -> dict:
    """functions/source_bias.stan's data: the number of biased sources, each
    row's (0: a reference), and no given normals for the bias curves (Stan's
    RNG draws them; stancal.stan.backends.base.fresh_prediction_normals gives
    them where generated quantities are rerun)."""
    return {"n_biased": len(biased_sources), "bias_of": bias_index(biased_sources, measurement),
            "bias_normals_new": np.zeros((0, len(biased_sources)))}
