"""SEPIA's Al-5083 flyer-plate example (github.com/lanl/SEPIA,
examples/Al_5083; Walters et al. 2018, J. Appl. Phys., doi:10.1063/1.5051442; data
LA-UR-18-20151) as stancal's long tables. Run once, from a SEPIA checkout:

    python case_studies/al5083/make_data.py /path/to/SEPIA/examples/Al_5083/data

Three symmetric-impact shots (104S, 105S, 106S), each reduced to ten features
of its free-surface velocity history: odd columns are times (us), even ones
velocities. SEPIA's example keeps the velocities V4, V6, V8, V10 of each shot
(12 features, numbered 1-12 here: shot 104S is 1-4, 105S 5-8, 106S 9-12) and
scales the runs' velocities by 10,000 (cm/us to m/s); so does this script.
Its observation covariance is diag(0.01 y) (m/s)^2, an sd of 0.1 sqrt(y)
m/s per feature: 0.8 m/s at 70 m/s, 2.2 m/s at 476 m/s. The 1,000 runs are a
Latin hypercube over 11 parameters, each shot's impact velocity among them
(vel1-vel3, cm/us): SEPIA calibrates all 11 as theta, shared by the one
observed vector, and so does the config here (three experiments, one per
shot, no simulator inputs)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

SHOTS = ("104S", "105S", "106S")
FEATURES = ["V4", "V6", "V8", "V10"]  # SEPIA's sel_features = [3, 5, 7, 9]: the velocities it calibrates to
TO_METRES_PER_SECOND = 10_000  # the runs' velocities are in cm/us
HERE = Path(__file__).parent


def main(source: Path) -> None:
    design = pd.read_csv(source / "Al.trial5.design.txt", sep=r"\s+")
    physical, runs = [], []
    for s, shot in enumerate(SHOTS):
        observed = pd.read_csv(source / f"features_cdf_obs{shot}.csv")
        observed.columns = [f"V{k + 1}" for k in range(observed.shape[1])]  # one file names them X1-X10
        simulated = pd.read_csv(source / f"features_cdf{shot}.csv")
        for f, column in enumerate(FEATURES):
            feature = 4 * s + f + 1
            y = float(observed[column].iloc[0])
            physical.append({"shot": shot, "feature": feature, "column": column, "velocity": y,
                             "sd": np.sqrt(0.01 * y)})  # SEPIA's Sigy = diag(0.01 y) is a covariance
            runs.append(design.assign(run=np.arange(len(design)), feature=feature,
                                      velocity=TO_METRES_PER_SECOND * simulated[column].to_numpy()))
    pd.DataFrame(physical).to_csv(HERE / "physical.csv", index=False, float_format="%.8g")
    table = pd.concat(runs, ignore_index=True).sort_values(["run", "feature"], kind="stable")
    table[["run", *design.columns, "feature", "velocity"]].to_csv(HERE / "runs.csv", index=False, float_format="%.8g")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
