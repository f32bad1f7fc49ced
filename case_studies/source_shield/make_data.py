"""Make the source-and-shield case study's data (fixed seed, so the shipped
CSV is reproducible): python case_studies/source_shield/make_data.py

Issue 30's counts case: 90 Poisson counts, theta = (source strength S,
attenuation mu). A point source of strength S, a shield of thickness s (cm)
and a detector at distance d (m); the simulator is the narrow-beam law,
S exp(-mu s) / d^2 counts per period. A real, broad beam also delivers photons
scattered in the shield: the counts are multiplied by a build-up factor
B = 1 + a mu s (the linear form; Shultis & Faw, "Radiation Shielding", ch. 8),
which the simulator lacks. The air pressure (1016 +- 5 hPa) and the operator
are recorded and play no part: decoys for the gap diagnosis. This is
case_studies/shield_buildup's physics and decoys on a larger grid, with the
source strength S unknown (there a fixed 2,000).
"""

from pathlib import Path

import numpy as np
import pandas as pd

SOURCE_TRUE = 600.0  # counts per period at 1 m without a shield
MU_TRUE = 0.35  # 1/cm, the shield's attenuation coefficient
BUILDUP_TRUE = 1.5  # a in B = 1 + a mu s


def true_mean(d, s):
    return SOURCE_TRUE * np.exp(-MU_TRUE * s) * (1 + BUILDUP_TRUE * MU_TRUE * s) / d**2


def main(folder: Path = Path(__file__).parent) -> None:
    rng = np.random.default_rng(20261125)
    d, s = np.meshgrid([0.5, 0.75, 1.0, 1.25, 1.5, 2.0], np.arange(15.0) * 8 / 14)
    d, s = d.ravel(), s.round(3).ravel()
    pd.DataFrame({
        "d": d, "s": s,
        "pressure": (1016 + 5 * rng.standard_normal(d.size)).round(1),  # hPa, irrelevant
        "operator": rng.choice(["ana", "ben", "chloe"], size=d.size),  # irrelevant
        "counts": rng.poisson(true_mean(d, s)),
    }).to_csv(folder / "physical.csv", index=False)


if __name__ == "__main__":
    main()
