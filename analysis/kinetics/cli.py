"""Command line of the kinetics stage: fit yield vs cumulative collision energy and write the
tables and Figures 9-11::

    python -m analysis.kinetics [--yields DATASET] [--twin-table CSV] [--out DIR]

Without ``--twin-table`` the energy inputs are the paper's Table 3 stand-in
(:func:`analysis.kinetics.energy_inputs.table3_energy_inputs`); every output says which source it
used. The output folder is checked before any work and replaced atomically
(:mod:`analysis.atomic_dir`).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from analysis import config
from analysis.kinetics.energy_inputs import (attach_cumulative_energy, energy_for_conditions,
                                             load_twin_energy_table, table3_energy_inputs)
from analysis.kinetics.fitting import KineticsFit, fit_kinetics
from analysis.kinetics.model import KineticsInputError
from analysis.kinetics.prediction import model_curves, regime_of


def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m analysis.kinetics",
                                description="Fit yield vs cumulative collision energy (paper Sec. 4) "
                                            "and write tables + Figures 9-11 to results/kinetics/.",
                                epilog="example: python -m analysis.kinetics --twin-table "
                                       "results/twin_tables/all_runs.csv --out results/kinetics")
    p.add_argument("--yields", type=Path, default=None,
                   help="measurement dataset folder with yields.csv (default: the SYNTHETIC "
                        "data/measurements/synthetic_yields_paper)")
    p.add_argument("--twin-table", type=Path, default=None,
                   help="CSV of twin outputs (frequency_hz, ball_diameter_m, v_mean_m_s, f_col_hz); "
                        "default: paper Table 3 measurements")
    p.add_argument("--velocity-assumption", choices=["interp", "as_is"], default="interp",
                   help="without --twin-table: how Table 3 (17.5/20.6 mm) speeds map to 20 mm")
    p.add_argument("--method", choices=["continuous", "candidates"], default="continuous",
                   help="regime-boundary search (default %(default)s)")
    p.add_argument("--n-boot", type=int, default=500,
                   help="case-resampling bootstrap replicates of the boundaries [replicates] "
                        "(0: none; default %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of the bootstrap [-] (default %(default)s)")
    p.add_argument("--out", type=Path, default=config.KINETICS_DIR,
                   help="output folder (default: results/kinetics)")
    return p


def _inputs(args):
    """The files and folders ``run`` reads: never an output."""
    from analysis import yield_dataset
    return [args.yields if args.yields is not None else yield_dataset.SYNTHETIC_DATASET_DIR,
            args.twin_table]


def run(args) -> Path:
    from analysis import yield_dataset
    from analysis.atomic_dir import check_out_dir, output_dir
    from analysis.plotting.kinetics_plots import write_kinetics_figures

    protected = _inputs(args)
    check_out_dir(args.out, protected)
    ds_path = args.yields if args.yields is not None else yield_dataset.SYNTHETIC_DATASET_DIR
    ds = yield_dataset.load_yield_dataset(ds_path)
    if args.twin_table is not None:
        inputs = load_twin_energy_table(args.twin_table)
    else:
        inputs = table3_energy_inputs(assumption=args.velocity_assumption)
    energy = energy_for_conditions(ds.conditions, inputs)
    data = attach_cumulative_energy(ds.yields, energy)
    label = ("SYNTHETIC yields" if ds.synthetic else f"yields: {ds.name}")
    src = f"{label}; energy: {energy['source'].iloc[0]}"
    phase = data["phase"] if "phase" in data.columns else None
    fit = fit_kinetics(data["e_tot_j"], data["yield_pct"], phase=phase, method=args.method,
                       n_boot=args.n_boot, random_state=args.seed, source=src)
    data["regime_fit"] = regime_of(data["e_tot_j"], fit)

    with output_dir(args.out, protected) as tmp:
        inputs.to_csv(tmp / "energy_inputs.csv", index=False)
        energy.to_csv(tmp / "energy_per_condition.csv", index=False)
        data.to_csv(tmp / "yields_with_energy.csv", index=False)
        fit.line.to_frame().to_csv(tmp / "powder_line.csv", index=False)
        pd.concat([b.to_frame() for b in [fit.boundaries] + fit.alternatives]).to_csv(
            tmp / "boundaries.csv", index=False)
        fit.save(tmp / "kinetics_fit.json")
        write_kinetics_figures(tmp, fit, data, inputs, model_curves(fit, data, energy),
                               ds.synthetic)
    return args.out


def main(argv=None) -> int:
    from analysis.atomic_dir import check_out_dir
    args = _build_parser().parse_args(argv)
    try:
        check_out_dir(args.out, _inputs(args))   # before any work
        out = run(args)
    except (KineticsInputError, ValueError, FileNotFoundError) as exc:  # OutputError: ValueError
        print(f"analysis.kinetics: error: {exc}", file=sys.stderr)
        return 2
    fit = KineticsFit.load(out / "kinetics_fit.json")
    p, se = fit.line.params, fit.line.stderr
    print(f"source: {fit.source}")
    print(f"powder line: a = {p['a_pct_per_kj']:.3f} +- {se['a_pct_per_kj']:.3f} %/kJ (se), "
          f"b = {p['b_pct']:.3f} +- {se['b_pct']:.3f} % (se), r2 = {fit.line.r2:.3f}, n = {fit.line.n}")
    for b in [fit.boundaries] + fit.alternatives:
        print(f"boundaries [{b.method}]: powder/wax {b.powder_wax_j:.0f} J "
              f"[{b.ci.loc['powder_wax_j', 'lower']:.0f}, {b.ci.loc['powder_wax_j', 'upper']:.0f}], "
              f"wax/complete {b.wax_complete_j:.0f} J "
              f"[{b.ci.loc['wax_complete_j', 'lower']:.0f}, {b.ci.loc['wax_complete_j', 'upper']:.0f}]")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
