"""Calibrate mu from the detector counts (Poisson, log link) with the cheap
simulator and from the runs, and draw what was learnt: the counts with their
predictive band, and the discrepancy on the log scale against the
finite-size effect the simulator lacks. Writes out/ (both calibration
reports) and out/discrepancy_vs_truth.png."""

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import stancal  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402
from stancal.reporting.report import write_calibration  # noqa: E402

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))
from make_data import MU_TRUE, solid_angle_factor  # noqa: E402


def main(out: Path = HERE / "out", draws: int = 1000) -> None:
    problem = load_config(HERE / "config.toml")
    fits = {}
    for method in ("koh", "koh_emulator"):
        fits[method] = stancal.calibrate(problem.data, simulator=problem.simulator, method=method,
                                         chains=4, warmup=draws, draws=draws, seed=1, out_dir=out / method)
        write_calibration(fits[method], out / method, fits[method].diagnostics.messages)
    d = problem.data.physical["d"].to_numpy()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, (method, result) in zip(axes, fits.items(), strict=False):
        delta = np.asarray(result.idata["at_observations"]["delta_gp"]).reshape(-1, len(d))
        order = np.argsort(d)
        low, mid, high = np.quantile(delta, [0.05, 0.5, 0.95], axis=0)
        ax.errorbar(d[order], mid[order], yerr=[(mid - low)[order], (high - mid)[order]], fmt="o", ms=3,
                    alpha=0.6, label="discrepancy delta (log counts), 90 %")
        grid = np.linspace(d.min(), d.max(), 100)
        ax.plot(grid, np.log(solid_angle_factor(grid)), color="k", label="log of the finite-size factor (truth)")
        mu = result.theta_summary()["mu"]
        ax.set_title(f"{method}: mu = {mu['q50']:.3f} [{mu['q05']:.3f}, {mu['q95']:.3f}] (truth {MU_TRUE})")
        ax.set_xlabel("distance d (m)")
        ax.axhline(0, color="grey", lw=0.8)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("log-scale discrepancy")
    fig.tight_layout()
    fig.savefig(out / "discrepancy_vs_truth.png", dpi=110)
    print(f"figures in {out}")


if __name__ == "__main__":
    main()
