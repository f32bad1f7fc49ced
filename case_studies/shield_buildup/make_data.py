"""Make the shield build-up case study's data (fixed seed, so the shipped CSV
is reproducible): python case_studies/shield_buildup/make_data.py

A point source, a shield of thickness s (cm) and a detector at distance d (m).
The simulator is the narrow-beam law, 2000 exp(-mu s) / d^2 counts per period.
A real, broad beam also delivers photons scattered in the shield: the counts
are multiplied by a build-up factor B = 1 + a mu s (the linear form; Shultis &
Faw, "Radiation Shielding", ch. 8), an effect that grows with the thickness
and that the simulator lacks. simulator_buildup.stan has it. The air pressure
(about 1016 +- 5 hPa) and the operator are recorded but play no part: decoys
for the gap diagnosis.
"""

from pathlib import Path

import numpy as np
import pandas as pd

MU_TRUE = 0.35  # 1/cm, the shield's attenuation coefficient
BUILDUP_TRUE = 1.5  # a in B = 1 + a mu s
SOURCE = 2000.0  # counts per period at 1 m without a shield


def narrow_beam(d, s, mu):
    return SOURCE * np.exp(-mu * s) / d**2


def true_mean(d, s):
    return narrow_beam(d, s, MU_TRUE) * (1 + BUILDUP_TRUE * MU_TRUE * s)


def main(folder: Path = Path(__file__).parent) -> None:
    rng = np.random.default_rng(20261123)
    d, s = np.meshgrid([0.5, 0.75, 1.0, 1.5, 2.0], np.arange(9.0))
    d, s = d.ravel(), s.ravel()
    pd.DataFrame({
        "d": d, "s": s,
        "pressure": (1016 + 5 * rng.standard_normal(d.size)).round(1),  # hPa, irrelevant
        "operator": rng.choice(["ana", "ben", "chloe"], size=d.size),  # irrelevant
        "counts": rng.poisson(true_mean(d, s)),
    }).to_csv(folder / "physical.csv", index=False)


if __name__ == "__main__":
    main()
