"""The deterministic emulator against the stochastic one (stochastic
kriging) on the stochastic_cooling case: k's 90 % interval against the
truth and its width, the measurement noise sd's posterior (truth 0.1 deg C),
the discrepancy's sd (truth: none), and the held-out readings' coverage by
the 90 % predictive bands of y, with the bands' mean width, in the quiet
half of the runs' scatter (t below 31 min) and the noisy half, at the
fitted settings (heldout.csv) and at settings without readings
(heldout_new.csv):
python case_studies/stochastic_cooling/compare.py [OUT_DIR] [--draws N]

Writes comparison.csv and each fit's report to OUT_DIR (default
stochastic_cooling_out) and prints the table (docs/noise.md)."""

import argparse
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pandas as pd

import stancal
from stancal.problem.config import load_config
from stancal.reporting.report import write_calibration

HERE = Path(__file__).parent


def _make_data():
    """This case's make_data.py, by path (other case studies have a make_data module too)."""
    name = "stochastic_cooling_make_data"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, HERE / "make_data.py")
        sys.modules[name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(sys.modules[name])
    return sys.modules[name]


K_TRUE, MEASUREMENT_SD, TIMES = _make_data().K_TRUE, _make_data().MEASUREMENT_SD, _make_data().TIMES
MIDDLE = 0.5 * (TIMES[0] + TIMES[-1])  # min: the runs' quiet half lies below, the noisy half above


def band_scores(result: stancal.CalibrationResult, heldout: pd.DataFrame, label: str) -> dict:
    """The 90 % bands of y at held-out readings: coverage and mean width in each half."""
    bands = result.predict(heldout[["t", "T0"]], seed=3)
    inside = (heldout["temperature"] >= bands["y_q05"]) & (heldout["temperature"] <= bands["y_q95"])
    width = bands["y_q95"] - bands["y_q05"]
    quiet = heldout["t"] < MIDDLE
    return {f"coverage_{label}_quiet": inside[quiet].mean(), f"coverage_{label}_noisy": inside[~quiet].mean(),
            f"band_width_{label}_quiet": width[quiet].mean(), f"band_width_{label}_noisy": width[~quiet].mean()}


def row(name: str, result: stancal.CalibrationResult, heldout: dict[str, pd.DataFrame], y_scale: float) -> dict:
    """One fit's line of the table."""
    posterior = result.idata["posterior"]
    k = np.asarray(posterior["theta"]).ravel()
    low, high = np.quantile(k, [0.05, 0.95])
    noise = np.asarray(posterior["noise_sd"]).ravel()  # the posterior is in original units
    d = result.diagnostics
    scores = {}
    for label, readings in heldout.items():
        scores |= band_scores(result, readings, label)
    return {"emulator": name, "k_mean": k.mean(), "k_q05": low, "k_q95": high, "k_covers_truth": low <= K_TRUE <= high,
            "k_width_90": high - low, "noise_sd_mean": noise.mean(),
            "noise_sd_q05": np.quantile(noise, 0.05), "noise_sd_q95": np.quantile(noise, 0.95),
            "delta_sd_mean": float(np.asarray(posterior["delta_sd"]).mean()), **scores,
            "emulator_nugget": result.emulator["hyperparameters"]["emulator_nugget"] * y_scale,
            "max_rhat": d.max_rhat, "divergences": d.divergences}


def main(out: Path, draws: int, chains: int = 4) -> pd.DataFrame:
    out.mkdir(parents=True, exist_ok=True)
    problem = load_config(HERE / "config.toml")
    heldout = {"fitted": pd.read_csv(HERE / "heldout.csv"), "new": pd.read_csv(HERE / "heldout_new.csv")}
    rows = []
    for name, stochastic in (("deterministic", False), ("stochastic", True)):
        result = stancal.calibrate(problem.data, method="modular", stochastic=stochastic, chains=chains, warmup=draws,
                                   draws=draws, seed=5, adapt_delta=0.95)
        write_calibration(result, out / name, units=problem.units)
        rows.append(row(name, result, heldout, problem.data.scaling.y_scale))
    table = pd.DataFrame(rows)
    table.to_csv(out / "comparison.csv", index=False)
    return table


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default="stochastic_cooling_out", type=Path)
    parser.add_argument("--draws", type=int, default=600, help="warmup and draws per chain")
    parser.add_argument("--chains", type=int, default=4)
    args = parser.parse_args()
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(main(args.out, args.draws, args.chains).round(4).T)
