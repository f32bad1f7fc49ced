"""Functional calibration of Young's modulus E(temperature) across the glass
transition, against the scalar-E fit that cannot follow it. Writes out/
(the functional fit's calibration report, theta_functions.png among its
figures) and out/modulus_vs_truth.png."""

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
from make_data import modulus  # noqa: E402


def main(out: Path = HERE / "out", draws: int = 1000) -> None:
    problem = load_config(HERE / "config.toml")
    settings = {"simulator": problem.simulator, "chains": 4, "warmup": draws, "draws": draws, "seed": 1}
    functional = stancal.calibrate(problem.data, functional=["E"], functional_inputs=["temperature"],
                                   out_dir=out, **settings)
    write_calibration(functional, out, functional.diagnostics.messages)
    scalar = stancal.calibrate(problem.data, method="koh_latent", discrepancy="none", **settings)
    curve = functional.theta_functions()["E"]
    temperature = np.array(curve["inputs"]["temperature"])
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    ax = axes[0]
    ax.fill_between(temperature, curve["q05"], curve["q95"], alpha=0.3, color="C4", label="E(T), 90 % band")
    ax.plot(temperature, curve["mean"], color="C4")
    ax.plot(temperature, modulus(temperature), "k--", label="true E(T)")
    e = scalar.theta_summary()["E"]
    ax.axhspan(e["q05"], e["q95"], color="C1", alpha=0.3, label="scalar E, 90 %")
    ax.set_xlabel("temperature (deg C)")
    ax.set_ylabel("Young's modulus E (GPa)")
    ax.legend(fontsize=8)
    ax = axes[1]
    observed = problem.data.physical["deflection"].to_numpy()
    for name, result in (("functional E(T)", functional), ("scalar E", scalar)):
        residual = result.predict()["zeta_mean"].to_numpy() - observed
        ax.scatter(problem.data.physical["temperature"], residual, s=12,
                   label=f"{name}: RMS {np.sqrt(np.mean(residual ** 2)):.2f} mm")
    ax.axhline(0, color="grey", lw=0.8)
    ax.set_xlabel("temperature (deg C)")
    ax.set_ylabel("fitted minus measured deflection (mm)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "modulus_vs_truth.png", dpi=110)
    print(f"figures in {out}")


if __name__ == "__main__":
    main()
