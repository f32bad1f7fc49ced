"""Calibrate the decay rate k from censored lab data, and compare with the
two naive fits: censored rows dropped, or imputed at the limit. Writes out/
(the censored fit's calibration report) and out/censoring_vs_naive.png."""

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import stancal  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402
from stancal.reporting.report import write_calibration  # noqa: E402

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))
from make_data import K_TRUE, naive_frames  # noqa: E402


def main(out: Path = HERE / "out", draws: int = 1000) -> None:
    problem = load_config(HERE / "config.toml")
    settings = {"simulator": problem.simulator, "method": "koh_latent", "discrepancy": "none", "chains": 4,
                    "warmup": draws, "draws": draws, "seed": 1}
    censored = stancal.calibrate(problem.data, out_dir=out, **settings)
    write_calibration(censored, out, censored.diagnostics.messages)
    fits = {"censored likelihood": censored}
    for name, frame in naive_frames(problem.data.source).items():
        data = stancal.CalibrationData(frame, problem.data.inputs, problem.data.output, {"k": (0.01, 0.5)})
        fits[{"drop": "censored rows dropped", "impute": "imputed at the limit"}[name]] = \
            stancal.calibrate(data, **settings)
    fig, ax = plt.subplots(figsize=(6.5, 3.2))
    for row, result in enumerate(fits.values()):
        k = result.theta_summary()["k"]
        ax.errorbar([k["q50"]], [row], xerr=[[k["q50"] - k["q05"]], [k["q95"] - k["q50"]]], fmt="o", capsize=4)
    ax.axvline(K_TRUE, color="k", ls="--", label="true k")
    ax.set_yticks(range(len(fits)), list(fits))
    ax.set_xlabel("decay rate k (1/h), median and 90 % interval")
    ax.locator_params(axis="x", nbins=6)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "censoring_vs_naive.png", dpi=110)
    print(f"figures in {out}")


if __name__ == "__main__":
    main()
