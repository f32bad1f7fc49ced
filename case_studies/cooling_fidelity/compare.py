"""theta's interval from the cheap and expensive runs together, against the
expensive runs alone and against the exact expensive simulator, and the
emulators' hold-out error at 500 fresh expensive runs:
python case_studies/cooling_fidelity/compare.py [OUT_DIR]

Writes intervals.csv, holdout.csv and intervals.png to OUT_DIR (default
cooling_fidelity_out) and prints both tables (docs/multifidelity.md)."""

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

import stancal  # noqa: E402
from stancal.fitting.stage_one import fidelity_levels  # noqa: E402
from stancal.numerics import multifidelity as mf  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402
from stancal.problem.data import bounds_of  # noqa: E402

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))
from make_data import K_TRUE, design, with_loss  # noqa: E402

MULTI_FIDELITY = "150 cheap + 15 expensive runs (multi-fidelity)"
SAMPLING = {"chains": 4, "warmup": 500, "draws": 1000, "seed": 7}


def fits(data: stancal.CalibrationData) -> dict[str, stancal.CalibrationResult]:
    expensive_only = stancal.CalibrationData(data.source, data.inputs, data.output, bounds_of(data.parameters),
                                             runs=data.runs)
    return {
        MULTI_FIDELITY: stancal.calibrate(
            data, method="modular", discrepancy="none", **SAMPLING),
        "15 expensive runs alone": stancal.calibrate(expensive_only, method="modular", discrepancy="none",
                                                     **SAMPLING),
        "exact expensive simulator (Stan)": stancal.calibrate(
            data, simulator=HERE / "simulator.stan", method="koh", discrepancy="none", **SAMPLING),
    }


def interval_table(results: dict[str, stancal.CalibrationResult]) -> pd.DataFrame:
    rows = []
    for name, result in results.items():
        k = np.asarray(result.idata["posterior"]["theta"]).reshape(-1)
        low, high = np.quantile(k, [0.05, 0.95])
        d = result.diagnostics
        rows.append({"fit": name, "mean": k.mean(), "q05": low, "q95": high, "width_90": high - low,
                     "covers_truth": bool(low <= K_TRUE <= high), "max_rhat": d.max_rhat,
                     "divergences": d.divergences})
    table = pd.DataFrame(rows)
    table["width_vs_exact"] = table["width_90"] / table["width_90"].iloc[-1]
    return table


def holdout_table(data: stancal.CalibrationData, result: stancal.CalibrationResult) -> pd.DataFrame:
    """RMS error (deg C) of each emulator's mean at 500 fresh expensive runs,
    and the share inside its 90 % band, everywhere and near the truth (k
    within 0.01 of it)."""
    fresh = design(500, seed=99)
    truth = with_loss(fresh["t"], fresh["T0"], fresh["k"]).to_numpy()
    near = (np.abs(fresh["k"] - K_TRUE) < 0.01).to_numpy()
    unit = np.hstack([data.scaling.to_unit(fresh, data.inputs), data.scaling.to_unit(fresh, data.theta_names)])
    levels = fidelity_levels(data, result.emulator["hyperparameters"]["levels"])
    plug_in = mf.fit_levels([lv.xt for lv in levels], [lv.y for lv in levels], seed=SAMPLING["seed"])
    alone = mf.fit_levels([levels[-1].xt], [levels[-1].y])
    rows = []
    for name, model in (("multi-fidelity (150 + 15 runs)", levels),
                        ("multi-fidelity, hyperparameters plugged in at the mode", plug_in),
                        ("expensive runs alone (15)", alone)):
        mean, variance = mf.predict(model, unit)
        error = data.scaling.original(mean) - truth
        inside = np.abs(error) <= 1.645 * np.sqrt(variance) * data.scaling.y_scale
        rows.append({"emulator": name, "rmse_degC": float(np.sqrt(np.mean(error**2))),
                     "max_error_degC": float(np.abs(error).max()), "within_90_band": float(inside.mean()),
                     "within_90_band_near_truth": float(inside[near].mean())})
    return pd.DataFrame(rows)


def figure(table: pd.DataFrame, path: Path) -> None:
    """Each fit's 90 % interval of k as a bar, its mean marked, the truth dashed."""
    fig, ax = plt.subplots(figsize=(9, 3))
    for i, row in table.iterrows():
        ax.plot([row["q05"], row["q95"]], [i, i], lw=6, solid_capstyle="butt", color=f"C{i}")
        ax.plot(row["mean"], i, "k|", ms=14)
    ax.axvline(K_TRUE, color="k", ls="--", lw=1, label=f"truth k = {K_TRUE}")
    ax.set_yticks(range(len(table)), table["fit"])
    ax.invert_yaxis()
    ax.set_xlabel("k (1/min): 90 % posterior interval, mean marked")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title("Cooling with two fidelities: the rate k's 90 % interval", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    data = load_config(HERE / "config.toml").data
    results = fits(data)
    intervals = interval_table(results)
    holdout = holdout_table(data, results[MULTI_FIDELITY])
    intervals.to_csv(out / "intervals.csv", index=False)
    holdout.to_csv(out / "holdout.csv", index=False)
    figure(intervals, out / "intervals.png")
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(intervals.round(4).to_string(index=False))
        print(holdout.round(4).to_string(index=False))


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("cooling_fidelity_out"))
