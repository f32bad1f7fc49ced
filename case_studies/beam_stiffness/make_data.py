"""Deflections of a polymer beam tested at temperatures across its glass
transition: the modulus E falls from about 3.5 GPa to 1.2 GPa around 55 deg C,
a logistic ramp. The simulator takes one E; functional calibration recovers
E(temperature). Writes physical.csv and runs.csv (simulator runs over
load and E, for the emulator)."""

from pathlib import Path

import numpy as np
import pandas as pd

from stancal.problem.design import latin_hypercube_with_corners

NOISE_SD = 0.1  # mm
E_BOUNDS = (0.5, 5.0)  # GPa


def modulus(temperature):
    """The true E(T): glassy 3.5 GPa, rubbery 1.2 GPa, transition at 55 deg C."""
    return 1.2 + 2.3 / (1 + np.exp((temperature - 55.0) / 5.0))


def simulator(load, E):
    return 1e3 * load * 0.125 / (3 * E * 1e9 * 2e-7)


def main(folder: Path = Path(__file__).parent) -> None:
    rng = np.random.default_rng(3)
    temperature, load = np.meshgrid(np.linspace(20, 90, 15), [50.0, 100.0, 150.0])
    temperature, load = temperature.ravel(), load.ravel()
    deflection = simulator(load, modulus(temperature)) + NOISE_SD * rng.standard_normal(load.size)
    pd.DataFrame({"load": load, "temperature": temperature, "deflection": deflection.round(4)}).to_csv(
        folder / "physical.csv", index=False)
    runs = pd.DataFrame(latin_hypercube_with_corners([50.0, E_BOUNDS[0]], [150.0, E_BOUNDS[1]], runs=30, seed=8),
                        columns=["load", "E"]).round(4)
    runs["deflection"] = simulator(runs.load, runs.E).round(5)
    runs.to_csv(folder / "runs.csv", index=False)


if __name__ == "__main__":
    main()
