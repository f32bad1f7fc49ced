"""What `stancal gap` costs against its baseline fit, and how far its ELPD
differences lie from a full K-fold answer (issue 30, target 2: at most 3x
the baseline fit's wall time, all candidates included; every ELPD difference
within one se of K-fold's).

    .venv/bin/python benchmarks/gap_cost.py [--case cooling] [--chains 4] [--warmup 1000] [--draws 1000]
        [--refits warm|cold] [--candidates warm|cold] [--all-candidates] [--kfold 10] [--seed 1]

In one process: the baseline fit alone (calibrate() with the gap's plan: a
constant in the discrepancy mean, on the local Dask cluster's machine), then
the gap diagnosis (diagnose_gap on a local cluster, as the CLI runs it),
then, with ``--kfold K``, the same diagnosis by K-fold cross-validation as
the reference (refits from scratch). The machine is shared and noisy: read the ratio, not the
seconds. ``--refits cold`` and ``--all-candidates`` switch the levers off
(refits from scratch; every candidate's unreliable points refitted);
``--candidates warm`` switches on one that is off by default (candidates'
fits started from the baseline's, which then runs first).
``--refits-only F`` measures the warm start alone: the baseline's refits on F
of 5 folds, cold and warm alternated, with their held-out ELPDs.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import stancal  # noqa: E402
from stancal.diagnosing.gap import diagnose_gap  # noqa: E402
from stancal.problem.config import load_config  # noqa: E402

TARGET_RATIO = 3.0  # issue 30, target 2


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    parser.add_argument("--case", default="cooling")
    parser.add_argument("--chains", type=int, default=4)
    parser.add_argument("--warmup", type=int, default=1000)
    parser.add_argument("--draws", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--refits", choices=["warm", "cold"], default="warm")
    parser.add_argument("--candidates", choices=["warm", "cold"], default="cold",
                        help="candidates' fits started from the baseline's (warm) or from Stan's inits")
    parser.add_argument("--all-candidates", action="store_true")
    parser.add_argument("--kfold", type=int, default=None, help="also the K-fold reference with this many folds")
    parser.add_argument("--json", type=Path, default=None, help="write the figures here too")
    parser.add_argument("--refits-only", type=int, default=None, metavar="FOLDS",
                        help="instead: the baseline's refits on this many of 5 folds, cold and warm alternated")
    return parser.parse_args()


def differences(analysis) -> dict[str, dict]:
    """Each candidate's ELPD difference to the baseline, its se, its scheme and refits."""
    summary = analysis.to_json()
    return {c["name"]: {"elpd_diff": round(c["elpd_diff"], 2), "se": round(c["elpd_diff_se"], 2),
                        "scheme": c["scheme"], "refits": c["refits"]} for c in summary["candidates"]}


def kfold_reference(problem, figures: dict, folds: int, seed: int, **options) -> None:
    """The same diagnosis by K-fold cross-validation from scratch, and each
    candidate's distance from it in K-fold's se, added to ``figures``."""
    reference = diagnose_gap(problem.data, problem.candidates, simulator=problem.simulator, seed=seed,
                             kfold=folds, warm_refits=False, warm_candidates=False, **options)
    kfold = differences(reference)
    figures["kfold"] = {"folds": folds, "candidates": kfold}
    figures["distance_in_se"] = {name: round(abs(c["elpd_diff"] - kfold[name]["elpd_diff"]) / kfold[name]["se"], 2)
                                 for name, c in figures["candidates"].items() if name in kfold}


def refit_lever(problem, model: dict, sampling: dict, args: argparse.Namespace) -> dict:
    """Lever 1 alone: the baseline's 5-fold refits, cold and warm-started
    alternated (so that both see the same load), their wall times and their
    held-out ELPD over the folds' points."""
    import numpy as np

    from stancal.diagnosing.scoring import held_out, kfold_tests, refit_rows
    from stancal.fitting.warm_start import warm_refit_options

    options = {"simulator": problem.simulator, "mean_intercept": True, **model, **sampling}
    data = problem.data
    started = time.perf_counter()
    full = stancal.calibrate(data, seed=args.seed, **options)
    figures = {"case": args.case, "sampling": sampling, "baseline_fit_s": round(time.perf_counter() - started, 1),
               "folds": []}
    for fold, test in enumerate(kfold_tests(len(data.physical), 5, args.seed)[:args.refits_only]):
        train, new = refit_rows(data, test)
        row = {"fold": fold, "points": len(test)}
        warm = warm_refit_options(full, np.setdiff1d(np.arange(len(data.physical)), test), sampling, args.seed)
        for kind, extra in (("cold", {}), ("warm", warm)):
            started = time.perf_counter()
            refit = stancal.calibrate(train, seed=args.seed + fold, new_points=new, **{**options, **extra})
            row[f"{kind}_s"] = round(time.perf_counter() - started, 1)
            row[f"{kind}_elpd"] = round(float(held_out(data, test, refit)[0].sum()), 2)
        print(json.dumps(row), flush=True)
        figures["folds"].append(row)
    figures["warm_over_cold"] = round(sum(r["warm_s"] for r in figures["folds"])
                                      / sum(r["cold_s"] for r in figures["folds"]), 2)
    return figures


def main() -> None:
    args = arguments()
    problem = load_config(ROOT / "case_studies" / args.case / "config.toml")
    sampling = {"chains": args.chains, "warmup": args.warmup, "draws": args.draws}
    model = {k: v for k, v in problem.model.items() if k in ("kernel", "discrepancy")}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if args.refits_only:
            figures = refit_lever(problem, model, sampling, args)
            print(json.dumps(figures, indent=1), flush=True)
            if args.json:
                args.json.write_text(json.dumps(figures, indent=1))
            return
        started = time.perf_counter()
        stancal.calibrate(problem.data, simulator=problem.simulator, mean_intercept=True, seed=args.seed,
                          **model, **sampling)
        baseline_s = time.perf_counter() - started
        started = time.perf_counter()
        levers = {"warm_refits": args.refits == "warm", "warm_candidates": args.candidates == "warm",
                  "every_candidate": args.all_candidates}
        gap = diagnose_gap(problem.data, problem.candidates, simulator=problem.simulator, seed=args.seed,
                           **levers, **model, **sampling)
        gap_s = time.perf_counter() - started
        figures = {"case": args.case, "sampling": sampling, "levers": levers,
                   "baseline_fit_s": round(baseline_s, 1), "gap_s": round(gap_s, 1),
                   "ratio": round(gap_s / baseline_s, 2), "target_ratio": TARGET_RATIO,
                   "gap_timing": gap.timing, "baseline_refits": gap.baseline_score.refits,
                   "candidates": differences(gap)}
        print(json.dumps(figures, indent=1), flush=True)
        if args.kfold:
            kfold_reference(problem, figures, args.kfold, args.seed, **model, **sampling)
            print(json.dumps({k: figures[k] for k in ("kfold", "distance_in_se")}, indent=1), flush=True)
    if args.json:
        args.json.write_text(json.dumps(figures, indent=1))


if __name__ == "__main__":
    main()
