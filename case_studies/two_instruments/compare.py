"""Pooled readings against a model of the instruments on the two_instruments
case: one noise sd for both and no bias (pooled iid) against one sd per
instrument with the camera's bias GP (per_source + biased_sources; Gu et al.
2023). For each fit: k's 90 % interval against the truth, the coverage of
the held-out readings (heldout.csv) by the 90 % predictive band of a new
reading, per instrument, and (bias model) the camera's bias band against the
true bias at the held-out settings:
python case_studies/two_instruments/compare.py [OUT_DIR] [--discrepancy gp] [--causes]

With --causes, two more fits separate the two changes: one sd per instrument
without the bias, and one sd for both with the camera's bias.

Writes comparison.csv and each fit's report to OUT_DIR (default
two_instruments_out) and prints the table (docs/noise.md)."""

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

import stancal
from stancal.problem.config import load_config
from stancal.reporting.report import write_calibration

HERE = Path(__file__).parent


def _make_data():
    """This case's make_data.py, by path (other case studies have a make_data module too)."""
    name = "two_instruments_make_data"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, HERE / "make_data.py")
        sys.modules[name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(sys.modules[name])
    return sys.modules[name]


K_TRUE, camera_bias = _make_data().K_TRUE, _make_data().camera_bias
SAMPLING = {"chains": 4, "warmup": 500, "draws": 500, "seed": 5}
# one sd for both instruments with the camera's bias: at 4 x (500 + 500) one chain's warm-up left the sd near the
# thermocouple's (R-hat 1.17, 2 divergences); 4 x (1000 + 1000) mixes (R-hat 1.004, none)
LONGER = {"warmup": 1000, "draws": 1000}
TARGET = (0.75, 0.98)  # the bar for 90 % bands
INPUTS = ["t", "T0"]
# each fit's report folder under OUT_DIR
FOLDERS = {"pooled iid": "pooled", "per_source, no bias": "per_source_no_bias",
           "iid + biased camera": "iid_biased", "per_source + biased camera": "per_source"}


def coverage_by_source(result: stancal.CalibrationResult, heldout: pd.DataFrame) -> dict[str, float]:
    """The share of each instrument's held-out readings inside the fit's 90 %
    band of a new reading (by that instrument, where the fit knows instruments)."""
    bands = result.predict(heldout.drop(columns="temperature"), seed=3)
    inside = (heldout["temperature"] >= bands["y_q05"]) & (heldout["temperature"] <= bands["y_q95"])
    return {source: float(inside[heldout["instrument"] == source].mean()) for source in ("thermocouple", "camera")}


def bias_coverage(result: stancal.CalibrationResult, heldout: pd.DataFrame) -> float:
    """The share of the held-out camera settings where the camera's bias band holds the true bias."""
    camera = heldout[heldout["instrument"] == "camera"]
    bands = result.predict(camera.drop(columns="temperature"), seed=3)
    truth = camera_bias(camera["t"].to_numpy())
    low, high = bands["bias_camera_q05"].to_numpy(), bands["bias_camera_q95"].to_numpy()
    return float(((low <= truth) & (truth <= high)).mean())


def row(name: str, result: stancal.CalibrationResult, heldout: pd.DataFrame, seconds: float) -> dict:
    k = np.asarray(result.idata["posterior"]["theta"]).reshape(-1)
    low, high = np.quantile(k, [0.05, 0.95])
    covered = coverage_by_source(result, heldout)
    d = result.diagnostics
    return {"model": name, "k_mean": float(k.mean()), "k_q05": float(low), "k_q95": float(high),
            "k_covers_truth": bool(low <= K_TRUE <= high), "k_shift_in_sd": float((k.mean() - K_TRUE) / k.std()),
            "coverage_thermocouple": covered["thermocouple"], "coverage_camera": covered["camera"],
            "both_in_target": all(TARGET[0] <= v <= TARGET[1] for v in covered.values()),
            "bias_band_covers": bias_coverage(result, heldout) if result.options.biased_sources else np.nan,
            "max_rhat": d.max_rhat, "divergences": d.divergences, "seconds": round(seconds, 1)}


def fits(discrepancy: str, causes: bool = False) -> dict[str, tuple[stancal.CalibrationResult, float]]:
    """The pooled fit (no source column: one sd, no bias) and the bias model
    (the config's); with ``causes``, between them one change at a time: one sd
    per instrument without the bias, and one sd for both with the camera's bias."""
    problem = load_config(HERE / "config.toml")
    frame = pd.read_csv(HERE / "physical.csv")
    pooled = stancal.CalibrationData(frame, INPUTS, "temperature", {"k": (0.01, 0.2)})
    model = {**problem.model, "discrepancy": discrepancy}
    models = [("pooled iid", pooled, {"noise": "iid", "discrepancy": discrepancy})]
    if causes:
        models += [("per_source, no bias", problem.data, {"noise": "per_source", "discrepancy": discrepancy}),
                   ("iid + biased camera", problem.data, {**model, "noise": "iid", **LONGER})]
    models.append(("per_source + biased camera", problem.data, model))
    out = {}
    for name, data, options in models:
        start = time.perf_counter()
        result = stancal.calibrate(data, simulator=problem.simulator, **{**SAMPLING, **options})
        out[name] = (result, time.perf_counter() - start)
    return out


def main(out: Path, discrepancy: str = "none", causes: bool = False) -> None:
    out.mkdir(parents=True, exist_ok=True)
    heldout = pd.read_csv(HERE / "heldout.csv")
    results = fits(discrepancy, causes)
    table = pd.DataFrame([row(name, result, heldout, seconds) for name, (result, seconds) in results.items()])
    table.to_csv(out / "comparison.csv", index=False)
    units = load_config(HERE / "config.toml").units
    for name, (result, _) in results.items():
        write_calibration(result, out / FOLDERS[name], units=units)
    with pd.option_context("display.width", 250, "display.max_columns", 20):
        print(table.round(4).to_string(index=False))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out", nargs="?", type=Path, default=Path("two_instruments_out"))
    parser.add_argument("--discrepancy", choices=("none", "gp"), default="none")
    parser.add_argument("--causes", action="store_true",
                        help="also fit per_source without the bias, and iid with the camera's bias")
    args = parser.parse_args()
    main(args.out, args.discrepancy, args.causes)
