"""Command line: ``stancal calibrate CONFIG.toml --out DIR``,
``stancal gap CONFIG.toml --out DIR``, ``stancal compare CONFIG.toml --out DIR``,
``stancal sbc CONFIG.toml --sims S --out DIR``, ``stancal design CONFIG.toml --runs N --out DIR``
and ``stancal compile CONFIG.toml ...``."""

from __future__ import annotations

import argparse
import functools
import logging
import re
import sys
import warnings
from dataclasses import fields
from pathlib import Path

from stancal.diagnosing.compare import METHODS
from stancal.diagnosing.sbc import SBC_CHAINS, SBC_WARMUP
from stancal.fitting.calibrate import calibrate
from stancal.fitting.cluster import IN_PROCESS
from stancal.fitting.plan import make_plan, model_keywords
from stancal.problem import advice
from stancal.problem.config import ConfigError, load_config
from stancal.problem.data import DataError
from stancal.problem.options import APPROXIMATIONS, DISCREPANCIES, EXACT_SIZE_LIMIT
from stancal.problem.sampling import NAMES as SAMPLER_NAMES
from stancal.problem.sampling import SamplerOptions
from stancal.problem.vector_data import VectorCalibrationData
from stancal.reporting.report import write_calibration
from stancal.stan.backends import BACKENDS, StanRuntimeError, get_backend
from stancal.stan.registry import DESIGN, L2, PROGRAMS, commands_taking, entry_methods, method_names
from stancal.stan.source import FlatProgram, StanProgramError

logger = logging.getLogger("stancal")


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Every option's help states its default (argparse's "(default: ...)",
    or the help's own words where the default is not a plain value), and a
    required option says so."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if action.required and action.option_strings:
            return f"{text} (required)"
        if "default:" in text or action.default is None:
            return text
        return super()._get_help_string(action)


_BACKEND_HELP = "Stan interface; default: $STANCAL_BACKEND, else cmdstanpy when CmdStan is installed, else pystan"
_METHOD_HELP = ("the calibration program; default: the config's [model] method, else koh with a Stan "
                "simulator, koh_emulator with runs only")
_SBC_DRAWS = "posterior draws kept per chain of each fit; default: 2 x --draws-per-fit spread over the chains"


def sampler_arguments(command: argparse.ArgumentParser, helps: dict[str, str] | None = None, **defaults) -> None:
    """The sampler's flags, made from stancal.problem.sampling.SamplerOptions
    (its help text and defaults, or a command's own ``helps`` and
    ``defaults``): every command that samples takes the same ones."""
    for option in fields(SamplerOptions):
        help_text = option.metadata["help"]
        if option.name == "draws" and defaults.get("draws", option.default) is None:
            help_text = _SBC_DRAWS
        help_text = (helps or {}).get(option.name, help_text)
        command.add_argument("--" + option.name.replace("_", "-"), type=option.metadata["type"],
                             default=defaults.get(option.name, option.default), help=help_text)


def sampler_options(args: argparse.Namespace) -> dict:
    """The sampler's flags the user gave or that have a default, checked
    (a bad one is a one-line error before the config is read)."""
    given = {name: getattr(args, name) for name in SAMPLER_NAMES if getattr(args, name) is not None}
    SamplerOptions.from_keywords(given)
    return given


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="stancal", description="Bayesian calibration of computer models with Stan",
                                     formatter_class=_HelpFormatter)
    commands = parser.add_subparsers(dest="command", required=True)
    add = functools.partial(commands.add_parser, formatter_class=_HelpFormatter)
    cal = add("calibrate", help="calibrate theta and write a report folder")
    gap = add("gap", help="diagnose the sim-to-real gap: where, which effect, how far")
    comp = add("compare", help="fit with koh, l2, orthogonal and scaled GP side by side")
    sbc = add("sbc", help="simulation-based calibration of the config's program and sampler")
    sbc.add_argument("config", type=Path, help="TOML config: its design, method and model")
    sbc.add_argument("--out", type=Path, required=True, help="output folder (sbc.json, ecdf.png)")
    sbc.add_argument("--sims", type=int, default=200, help="simulated data sets (S)")
    sbc.add_argument("--draws-per-fit", type=int, default=100, help="thinned posterior draws per fit (L)")
    sbc.add_argument("--level", type=float, default=0.95, help="a parameter is rejected below p = 1 - level")
    sbc.add_argument("--subset", type=int, nargs="+", default=None, metavar="S",
                     help="fit only these simulations (numbered from 0), each with its whole-run truth, data and "
                          "seed: e.g. to refit some with longer chains into another --out (default: all of --sims)")
    sampler_arguments(sbc, chains=SBC_CHAINS, warmup=SBC_WARMUP, draws=None)
    sbc.add_argument("--backend", choices=BACKENDS, default=None, help=_BACKEND_HELP)
    for command in (cal, gap, comp):
        command.add_argument("config", type=Path, help="TOML config (paths inside are relative to it)")
        command.add_argument("--out", type=Path, required=True, help="output folder")
        sampler_arguments(command)
        command.add_argument("--backend", choices=BACKENDS, default=None, help=_BACKEND_HELP)
    for command in (cal, gap, comp):
        command.add_argument("--approximation", choices=APPROXIMATIONS, default=None,
                             help="exact (dense GPs), hsgp (scalable) or auto (hsgp above "
                                  f"{EXACT_SIZE_LIMIT} points plus runs); default: the config's, else auto")
    for command in (cal, gap):
        command.add_argument("--method", choices=list(dict.fromkeys([*method_names("scalar"), *method_names("vector"),
                                                                      *([L2] if command is cal else [])])),
                             help=_METHOD_HELP)
    cal.add_argument("--discrepancy", choices=list(DISCREPANCIES),
                     help="gp (KOH), orthogonal (Plumlee 2017), scaled (S-GaSP) or none; "
                          "default: the config's [model] discrepancy, else gp")
    gap.add_argument("--discrepancy", choices=[d for d in DISCREPANCIES if d != "none"],
                     help="the discrepancy every fit carries (the gap is measured in it): gp (KOH), orthogonal "
                          "(Plumlee 2017) or scaled (S-GaSP, scalar outputs); default: the config's [model] "
                          "discrepancy, else gp")
    comp.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS), help="the methods compared")
    for command in (gap, comp, sbc):
        command.add_argument("--scheduler", default=None, metavar="ADDRESS",
                             help="run the fits on this Dask cluster (e.g. tcp://10.0.0.5:8786); default: a "
                                  f"local cluster, one worker per core; '{IN_PROCESS}': one after another here")
    design_arguments(add(DESIGN, help="history matching in waves: NROY, and the next simulator runs and experiments"))
    build = add("compile", help="compile every Stan program the configs need, in parallel")
    build.add_argument("configs", type=Path, nargs="+", help="TOML configs")
    build.add_argument("--all-methods", action="store_true",
                       help="every method the problem admits, not only the configured one")
    build.add_argument("--backend", choices=BACKENDS, default=None, help=_BACKEND_HELP)
    gap.add_argument("--kfold", type=int, default=None,
                     help="compare by K-fold cross-validation with this many folds instead of PSIS-LOO; "
                          "default: PSIS-LOO, with 5-fold when Pareto k is high at many observations")
    return parser


def design_arguments(command: argparse.ArgumentParser) -> None:
    from stancal.designing.loop import CRITERIA, POSTERIOR_SAMPLER
    from stancal.designing.targets import CUTOFF

    command.add_argument("config", type=Path, help="TOML config with [simulator] runs (paths relative to it)")
    command.add_argument("--runs", type=int, required=True, help="simulator runs to propose (N)")
    command.add_argument("--out", type=Path, required=True,
                         help="design folder; run again with the same folder, after adding the runs, for the next wave")
    command.add_argument("--criterion", choices=CRITERIA, default="nroy",
                         help="nroy: space-filling in NROY x the inputs' range; posterior: where the emulator's "
                              "variance weighted by theta's posterior (a modular fit) falls most")
    command.add_argument("--experiments", type=int, default=0,
                         help="also propose this many physical input settings (next_experiments.csv)")
    command.add_argument("--cutoff", type=float, default=None,
                         help=f"implausibility cutoff; default: the config's [design] cutoff, else {CUTOFF:g}")
    # a design is reproducible by default: its seed is 1, not a fresh one
    sampler_arguments(command, {"seed": "random seed of the NROY sample, the candidates and the posterior's fit"},
                      **POSTERIOR_SAMPLER, seed=1)
    command.add_argument("--backend", choices=BACKENDS, default=None, help=_BACKEND_HELP)


def _stancal_warnings(caught) -> list[str]:
    return [str(w.message) for w in caught if w.category.__module__.startswith("stancal")]


def run_gap(args: argparse.Namespace) -> dict:
    from stancal.diagnosing.gap import diagnose_gap
    from stancal.reporting.gap_report import write_gap_report

    problem = load_config(args.config)
    if not problem.candidates:
        raise ConfigError("config: `stancal gap` needs a [candidates] section")
    model = dict(problem.model)  # the config's whole model (its noise too): every fit, baseline and candidates
    method = args.method or model.get("method")
    model.pop("method", None)
    model["discrepancy"] = _gap_discrepancy(args, model)
    if args.approximation:
        model["approximation"] = args.approximation
    # no args.out.mkdir here: the fits and reports create it, so a failure before sampling leaves none
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        analysis = diagnose_gap(problem.data, problem.candidates, simulator=problem.simulator, method=method,
                                **model, **sampler_options(args), backend=args.backend,
                                out_dir=args.out, kfold=args.kfold, scheduler=args.scheduler)
    summary = write_gap_report(analysis, args.out, problem.units)
    write_calibration(analysis.baseline, args.out / "baseline",
          analysis.baseline.diagnostics.messages if analysis.baseline.diagnostics else [], problem.units)
    for message in _stancal_warnings(caught):
        print(f"warning: {message}", file=sys.stderr)
    return summary


def _gap_discrepancy(args: argparse.Namespace, model: dict) -> str:
    discrepancy = args.discrepancy or model.get("discrepancy", "gp")
    if discrepancy == "none":
        raise ConfigError("config: `stancal gap` measures the gap in the discrepancy: [model] discrepancy = "
                          "'none' leaves none to measure; use gp, orthogonal or scaled")
    return discrepancy


def _require_command(problem, command: str) -> None:
    """Refuse an output kind none of whose programs the command takes (the
    registry's Program.commands)."""
    output = "vector" if isinstance(problem.data, VectorCalibrationData) else "scalar"
    if not commands_taking(command, output):
        takers = sorted({p.output for p in PROGRAMS.values() if command in p.commands})
        raise ConfigError(f"`stancal {command}` does not take a {output} output yet (it takes {' and '.join(takers)} "
                          f"outputs); `stancal calibrate` and `stancal gap` do")


def run_calibrate(args: argparse.Namespace) -> dict:
    problem = load_config(args.config)
    vector = isinstance(problem.data, VectorCalibrationData)
    if vector and args.approximation:
        raise ConfigError("--approximation does not apply to a vector output (koh_vector, modular_vector)")
    model = dict(problem.model)
    configured_method = model.pop("method", None)
    if args.discrepancy:
        model["discrepancy"] = args.discrepancy
    if args.approximation:
        model["approximation"] = args.approximation
    sampler = {**sampler_options(args), "backend": args.backend, "out_dir": args.out}
    # no args.out.mkdir here: the fits and reports create it, so a failure before sampling leaves none
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if vector:
            from stancal.fitting.vector_calibrate import calibrate_vector

            result = calibrate_vector(problem.data, simulator=problem.simulator,
                                      method=args.method or configured_method, **sampler, **model)
        else:
            result = calibrate(problem.data, simulator=problem.simulator, method=args.method or configured_method,
                               **sampler, **model)
    summary = write_calibration(result, args.out, _stancal_warnings(caught), problem.units)
    for message in summary["warnings"]:
        print(f"warning: {message}", file=sys.stderr)
    return summary


def run_compare(args: argparse.Namespace) -> dict:
    from stancal.diagnosing.compare import compare_methods
    from stancal.reporting.compare_report import write_comparison

    problem = load_config(args.config)
    _require_command(problem, "compare")
    model = {k: v for k, v in problem.model.items() if k not in ("method", "discrepancy")}
    if args.approximation:
        model["approximation"] = args.approximation
    # no args.out.mkdir here: the fits and reports create it, so a failure before sampling leaves none
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        comparison = compare_methods(problem.data, simulator=problem.simulator,
                                     methods=tuple(args.methods), **sampler_options(args),
                                     backend=args.backend, out_dir=args.out, scheduler=args.scheduler,
                                     **model)
    for fit in comparison.fits:
        if fit.result is not None:
            write_calibration(fit.result, args.out / fit.name,
                              fit.result.diagnostics.messages if fit.result.diagnostics else [], problem.units)
    summary = write_comparison(comparison, args.out, problem.units)
    for message in _stancal_warnings(caught):
        print(f"warning: {message}", file=sys.stderr)
    return summary


def run_sbc(args: argparse.Namespace) -> dict:
    from stancal.diagnosing.sbc import simulation_based_calibration
    from stancal.reporting.sbc_report import write_sbc_report

    problem = load_config(args.config)
    _require_command(problem, "sbc")
    model = {k: v for k, v in problem.model.items() if k != "approximation"}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = simulation_based_calibration(
            problem.data, simulator=problem.simulator, simulations=args.sims, draws_per_fit=args.draws_per_fit,
            level=args.level, out_dir=args.out, subset=args.subset, **sampler_options(args),
            backend=args.backend, scheduler=args.scheduler, **model)
    write_sbc_report(result, args.out)
    for message in _stancal_warnings(caught):  # each naming its simulation
        print(f"warning: {message}", file=sys.stderr)
    return result.to_json()


def run_design(args: argparse.Namespace) -> dict:
    from stancal.designing.loop import design
    from stancal.designing.targets import DesignSettings
    from stancal.designing.waves import load_waves
    from stancal.reporting.design_report import write_design

    # before the config is read and any NROY work is done, on purpose: a bad flag is one line at once, not an
    # error after minutes of history matching (propose_runs checks --runs again for callers of the API)
    for flag, value, lowest in (("--runs", args.runs, 1), ("--experiments", args.experiments, 0)):
        if value < lowest:
            raise ValueError(f"{flag} must be at least {lowest}; got {value}")
    if args.cutoff is not None and not args.cutoff > 0:
        raise ValueError(f"--cutoff must be positive; got {args.cutoff}")
    problem = load_config(args.config)
    _require_command(problem, DESIGN)
    settings = DesignSettings(**{**problem.design, **({} if args.cutoff is None else {"cutoff": args.cutoff})})
    waves = load_waves(args.out, problem.data)
    sampler = {k: v for k, v in sampler_options(args).items() if k != "seed"}
    model = {k: v for k, v in problem.model.items() if k not in ("method", "program")}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = design(problem.data, args.runs, criterion=args.criterion, experiments=args.experiments,
                        settings=settings, waves=waves, seed=args.seed, simulator=problem.simulator,
                        backend=args.backend, **sampler, **model)
    summary = write_design(result, args.out, problem.units)
    for message in _stancal_warnings(caught):
        print(f"warning: {message}", file=sys.stderr)
    return summary


def config_programs(problem, all_methods: bool) -> list[FlatProgram]:
    """The programs that calibrate and gap run on a config: its method (or
    every method the problem admits) and its candidates' simulator variants."""
    from stancal.diagnosing.gap import variant_program

    vector = isinstance(problem.data, VectorCalibrationData)
    model = dict(problem.model)
    configured, program = model.pop("method", None), model.pop("program", None)
    model = {k: tuple(v) if isinstance(v, list) else v for k, v in model_keywords(model, vector).items()}
    methods = [configured, *(entry_methods("vector" if vector else "scalar") if all_methods else [])]
    programs, plans = [], []
    for method in dict.fromkeys(methods):
        try:
            plans.append(make_plan(problem.data, problem.simulator, method,
                                   program if method == configured else None, **model))
        except ValueError:
            if method == configured:  # the config's own model: what it cannot run is said, not skipped
                raise
            continue  # --all-methods: a method this problem cannot run
        programs += plans[-1].stan_programs()
    return programs + [variant_program(problem.data, c, plans[0] if plans else None)
                       for c in problem.candidates if c.kind == "variant"]


def run_compile(args: argparse.Namespace) -> dict:
    programs = []
    for config in args.configs:  # every config planned before anything compiles
        try:
            programs += config_programs(load_config(config), args.all_methods)
        except ValueError as err:
            raise ConfigError(in_config(config, err)) from None
    get_backend(args.backend).compile(programs)
    return {"programs": len({p.code for p in programs})}


def in_config(config: Path, err: Exception) -> str:
    """An input error of a config-driven command, one line, naming the
    config unless it names a file already (a CSV's line, a Stan program's)
    or a command-line flag (checked before the config is read)."""
    message = _one_line(err).removeprefix("config: ")
    named = message.startswith("--") or str(config) in message or re.search(r"\.(csv|stan|toml)\b", message)
    return message if named else f"{config}: {message}"


def _one_line(err: Exception) -> str:
    """stanc puts the location first and the reason last: keep both."""
    lines = [line.strip() for line in str(err).strip().splitlines() if line.strip()]
    if not lines:
        return type(err).__name__
    return lines[0] if len(lines) == 1 else f"{lines[0]} {lines[-1]}"


def main(argv: list[str] | None = None) -> int:
    level = logger.level  # restored: a script or test that calls main() keeps its own logging
    try:
        with advice.spoken_to(advice.CLI):  # advice in messages names flags, config keys and report files
            return _main(argv)
    finally:
        logger.setLevel(level)


def _main(argv: list[str] | None) -> int:
    args = _parser().parse_args(argv)
    # stancal's own messages at INFO; other libraries' (setuptools prints each
    # g++ command of a compile) at WARNING
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    logger.setLevel(logging.INFO)
    try:
        if hasattr(args, "chains"):  # the sampler's options, checked before the config is read
            sampler_options(args)
        summary = {"gap": run_gap, "compare": run_compare, "calibrate": run_calibrate,
                   "compile": run_compile, "sbc": run_sbc, DESIGN: run_design}[args.command](args)
    except (ConfigError, DataError, StanProgramError, StanRuntimeError, ValueError, RuntimeError) as err:
        config = getattr(args, "config", None)  # an input error names the config it came from
        message = in_config(config, err) if config and isinstance(err, ValueError) else _one_line(err)
        print(f"stancal: error: {message}", file=sys.stderr)
        return 2
    if args.command == "compile":
        print(f"{summary['programs']} Stan programs compiled or found in the cache")
        return 0
    if args.command == "gap":
        for failure in summary["failed"]:
            print(f"warning: {failure['name']} failed twice and is left out: {failure['error']}", file=sys.stderr)
        if not summary["candidates"]:
            print(f"gap: every candidate's fit failed; report in {args.out / 'report.md'}")
            return 1
        best = summary["candidates"][0]
        print(f"gap: best candidate {best['name']} (ELPD {best['elpd_diff']:+.1f} ± "
              f"{best['elpd_diff_se']:.1f}, shrinkage {best['shrinkage']['mean']:.2f}); "
              f"report in {args.out / 'report.md'}")
        return 0
    if args.command == DESIGN:
        print(f"design: wave {len(summary['waves'])}, NROY {summary['nroy_fraction']:.3g} of theta's box; "
              f"{summary['proposed_runs']} runs in {args.out / 'next_runs.csv'}; report in {args.out / 'report.md'}")
        return 0
    if args.command == "sbc":
        for _name, row in summary["parameters"].items():
            print(row["verdict"])
        print(f"sbc: {summary['simulations']} simulations, {summary['draws_per_fit']} draws each; "
              f"results in {args.out / 'sbc.json'}")
        return 0
    if args.command == "compare":
        for row in summary["methods"]:
            if row.get("skipped"):
                print(f"{row['method']}: skipped, {row['skipped']}")
            else:
                print(f"{row['method']}: " + ", ".join(
                    f"{name} = {row[f'{name}_q50']:.4g} [{row[f'{name}_q05']:.4g}, {row[f'{name}_q95']:.4g}]"
                    for name in summary["theta_names"]) + f"; discrepancy RMS {row['discrepancy_rms_q50']:.3g}")
        print(f"comparison in {args.out / 'report.md'}")
        return 0
    theta = ", ".join(f"{k} = {v['mean']:.4g} [{v['q05']:.4g}, {v['q95']:.4g}]" for k, v in summary["theta"].items())
    print(f"{summary['method']}: {theta}; results in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
