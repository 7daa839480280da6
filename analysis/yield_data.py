"""Yield tables: a validating loader for measured PET yields, and a SYNTHETIC generator.

Loader
------
A measurement dataset (DESIGN.md) ``data/measurements/<name>/`` holds ``dataset.json``,
``conditions.csv`` (condition_id, frequency_hz, ball_diameter_mm, ...) and ``yields.csv``
(condition_id, time_min, yield_pct, optional yield_sd_pct and phase). :func:`load_yield_dataset`
reads them; any problem raises :class:`YieldDataError` naming the file, row (1-based line number
in the file, header = line 1) and column.

The loader is a view: the contract of conditions.csv and yields.csv (columns, units, numeric
rules, ordering, phase labels) is declared once, in :mod:`analysis.measurements`, which reads and
validates both files (:func:`analysis.measurements.read_table`,
:func:`~analysis.measurements.validate_conditions_table`,
:func:`~analysis.measurements.validate_yields_table`). This module only presents the result:
its row numbers are file lines, phase labels are lower case or NA, columns outside the contract
get pandas' CSV types, and dataset.json needs only ``name`` (no summary.csv is needed).

Synthetic generator
-------------------
The paper's yield tables (SI S2-S4) are not available, so :func:`generate_synthetic_yields`
makes data consistent with everything the paper states (Section 4): one 20 mm steel ball,
25 / 27.5 / 30 Hz; yield linear in E_tot in the powder regime with Table 4's line
(a = 9.49 %/kJ, b = -3.03 %) and r2 ~ 0.966; powder/wax boundary 4593 J, wax/complete 7126 J;
complete depolymerisation first observed at 20 / 25 / 40 min for 30 / 27.5 / 25 Hz; linear up to
about 12.5 min at 30 Hz.

Noise model (documented, seeded, all draws from ``numpy.random.default_rng(seed)``):

* energy: E_tot = P t with P = E_kin f_col per condition from :func:`analysis.kinetics.
  table3_energy_inputs` (Table 3 speeds interpolated to 20 mm, f_col = 2 f) - the same inputs the
  kinetics CLI uses by default, so the fit sees the true energies (no error in x);
* powder (E < E1): X = a E[kJ] + b + eps, eps ~ N(0, sigma_p^2), i.i.d., with sigma_p chosen so
  the expected r2 of the powder line over the sampling design equals ``r2_target``:
  sigma_p^2 = a^2 var(E_powder) (1 - r2) / r2;
* wax (E1 <= E < E2): the straight ramp from the powder line's value at E1 to 100 % at E2, plus
  N(0, sigma_wax^2) (the paper: greater spread in the wax regime);
* complete (E >= E2): 100 % - |N(0, sigma_complete^2)|;
* every yield clipped to [0, 100] %; phase label = the true regime of the sample's energy.

Sampling design: every 2.5 min at 30 and 27.5 Hz (to 20 and 25 min), every 5 min to 30 min and
then 40 min at 25 Hz. With the default energies complete depolymerisation is first sampled at
20 / 25 / 40 min as the paper reports (a 35 min sample at 25 Hz would already be complete: at the
synthetic power the 7126 J boundary is passed at 31.4 min, so the schedule skips 35 min).

Table 4's "+-" is read as 95 % confidence half-widths (the paper's Figure 11 band is a 95 %
interval). With this design the powder fit's expected half-widths are about +-1.04 %/kJ for a
(matching the paper's +-1.00) and +-2.9 % for b (wider than the paper's +-1.70: the paper's b
interval is narrower than its a interval and r2 allow for powder samples spread over 0.7-4.6 kJ).

Everything written by the generator is labelled SYNTHETIC (``"synthetic": true`` in
dataset.json).

CLI::

    python -m analysis.yield_data generate --out data/measurements/synthetic_yields_paper --seed 0
    python -m analysis.yield_data check data/measurements/<name>
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from analysis import kinetics
from analysis.yield_dataset import (PHASES, SYNTHETIC_DATASET_DIR,  # noqa: F401  (re-exported)
                                    SYNTHETIC_DATASET_NAME, YieldDataError, YieldDataset,
                                    load_yield_dataset, validate_conditions, validate_yields)

#: how a generated dataset's dataset.json names its writer ("source")
GENERATOR_SOURCE = "analysis.yield_data.generate_synthetic_yields"

#: sampling times [min] per frequency [Hz] of the synthetic design (see module docstring)
DEFAULT_SCHEDULE_MIN = {
    30.0: [2.5, 5.0, 7.5, 10.0, 12.5, 15.0, 17.5, 20.0],
    27.5: [2.5, 5.0, 7.5, 10.0, 12.5, 15.0, 17.5, 20.0, 22.5, 25.0],
    25.0: [5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 40.0],
}


# --------------------------------------------------------------------------------------------
# synthetic generator
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SyntheticYieldTruth:
    """Truth and noise of the synthetic yield model (defaults: the paper's statements).

    Attributes
    ----------
    slope_pct_per_kj, intercept_pct : powder line X = a E[kJ] + b [%/kJ, %]
    powder_wax_j, wax_complete_j : regime boundaries [J]
    r2_target : expected r2 of the powder line over the design (sets sigma_powder_pct)
    sigma_wax_pct, sigma_complete_pct : noise sd in the wax and complete regimes [%]
    sigma_powder_pct : powder noise sd [%]; None -> derived from r2_target and the design
    """

    slope_pct_per_kj: float = kinetics.PAPER_SLOPE_PCT_PER_KJ
    intercept_pct: float = kinetics.PAPER_INTERCEPT_PCT
    powder_wax_j: float = kinetics.PAPER_POWDER_WAX_J
    wax_complete_j: float = kinetics.PAPER_WAX_COMPLETE_J
    r2_target: float = 0.966
    sigma_wax_pct: float = 5.0
    sigma_complete_pct: float = 1.0
    sigma_powder_pct: float | None = None


def true_yield_pct(e_tot_j, truth: SyntheticYieldTruth = SyntheticYieldTruth()) -> np.ndarray:
    """Noise-free yield [%] at cumulative energies e_tot_j [J], shape (n,)."""
    e = np.asarray(e_tot_j, dtype=float)
    a, b = truth.slope_pct_per_kj, truth.intercept_pct
    e1, e2 = truth.powder_wax_j, truth.wax_complete_j
    x1 = a * e1 / 1e3 + b
    return np.where(e < e1, a * e / 1e3 + b,
                    np.where(e < e2, x1 + (100.0 - x1) * (e - e1) / (e2 - e1), 100.0))


def true_phase(e_tot_j, truth: SyntheticYieldTruth = SyntheticYieldTruth()) -> np.ndarray:
    """True regime name per energy, shape (n,)."""
    e = np.asarray(e_tot_j, dtype=float)
    return np.where(e < truth.powder_wax_j, "powder",
                    np.where(e < truth.wax_complete_j, "wax", "complete"))


def synthetic_energy_inputs(frequencies_hz=(25.0, 27.5, 30.0),
                            ball_diameter_mm: float = kinetics.YIELD_BALL_DIAMETER_MM,
                            assumption: str = "interp") -> pd.DataFrame:
    """Per-condition energy inputs for the synthetic data: conditions table + e_kin_j, f_col_hz,
    power_w, source (from paper Table 3, see :func:`analysis.kinetics.table3_energy_inputs`)."""
    inputs = kinetics.table3_energy_inputs(ball_diameters_mm=(ball_diameter_mm,),
                                           assumption=assumption)
    cond = pd.DataFrame({"condition_id": [f"f{f:g}_d{ball_diameter_mm:g}" for f in frequencies_hz],
                         "frequency_hz": [float(f) for f in frequencies_hz],
                         "ball_diameter_mm": float(ball_diameter_mm), "n_balls": 1})
    return kinetics.energy_for_conditions(cond, inputs)


def powder_sigma_pct(e_powder_j, truth: SyntheticYieldTruth) -> float:
    """sigma_p such that E[r2] of the powder line over these energies ~ truth.r2_target."""
    if truth.sigma_powder_pct is not None:
        return float(truth.sigma_powder_pct)
    e_kj = np.asarray(e_powder_j, dtype=float) / 1e3
    r2 = truth.r2_target
    return float(np.sqrt(truth.slope_pct_per_kj ** 2 * np.var(e_kj, ddof=1) * (1 - r2) / r2))


def generate_synthetic_yields(truth: SyntheticYieldTruth = SyntheticYieldTruth(),
                              schedule_min: dict | None = None, energy: pd.DataFrame | None = None,
                              n_replicates: int = 1, seed=0):
    """Draw one SYNTHETIC yield dataset.

    Parameters
    ----------
    truth : SyntheticYieldTruth
    schedule_min : dict {frequency_hz: list of times [min]} (default DEFAULT_SCHEDULE_MIN)
    energy : DataFrame, optional - per-condition energy (condition_id, frequency_hz,
        ball_diameter_mm, e_kin_j, f_col_hz, power_w, source); default
        :func:`synthetic_energy_inputs` for the schedule's frequencies
    n_replicates : int - samples per (condition, time)
    seed : int or Generator

    Returns
    -------
    conditions : DataFrame - condition_id, frequency_hz, ball_diameter_mm, n_balls
    yields : DataFrame - condition_id, time_min, yield_pct, phase, e_tot_j_true, yield_pct_true
    meta : dict - dataset.json content (``synthetic: true``, truth, noise model, seed)
    """
    schedule = DEFAULT_SCHEDULE_MIN if schedule_min is None else schedule_min
    if energy is None:
        energy = synthetic_energy_inputs(tuple(schedule))
    rng = np.random.default_rng(seed)
    rows = []
    for _, c in energy.iterrows():
        times = schedule[float(c["frequency_hz"])]
        for t in times:
            for _ in range(int(n_replicates)):
                rows.append(dict(condition_id=c["condition_id"], time_min=float(t),
                                 e_tot_j_true=float(c["power_w"]) * t * 60.0))
    y = pd.DataFrame(rows)
    e = y["e_tot_j_true"].to_numpy()
    ph = true_phase(e, truth)
    sig_p = powder_sigma_pct(e[ph == "powder"], truth)
    mean = true_yield_pct(e, truth)
    noise = np.where(ph == "powder", rng.normal(0, sig_p, e.size),
                     np.where(ph == "wax", rng.normal(0, truth.sigma_wax_pct, e.size),
                              -np.abs(rng.normal(0, truth.sigma_complete_pct, e.size))))
    y["yield_pct"] = np.clip(mean + noise, 0.0, 100.0).round(3)
    y["phase"] = ph
    y["yield_pct_true"] = mean
    y = y[["condition_id", "time_min", "yield_pct", "phase", "e_tot_j_true", "yield_pct_true"]]
    cond = energy[["condition_id", "frequency_hz", "ball_diameter_mm"]].copy()
    cond["n_balls"] = 1
    truth_d = asdict(truth)
    truth_d["sigma_powder_pct"] = sig_p
    meta = {
        "name": SYNTHETIC_DATASET_NAME,
        "synthetic": True,
        "description": ("SYNTHETIC PET yields (NOT measured): generated from the paper's stated "
                        "kinetics (Table 4 line, boundaries 4593 / 7126 J, r2 0.966, completion "
                        "at 20/25/40 min for 30/27.5/25 Hz), one 20 mm steel ball, 25 mL jar."),
        "source": GENERATOR_SOURCE + "; Anglou et al. 2024 Section 4",
        "velocity_frame": "lab",
        "seed": seed if isinstance(seed, int) else None,
        "n_replicates": int(n_replicates),
        "truth": truth_d,
        "energy_source": str(energy["source"].iloc[0]),
        "energy_per_condition": energy[["condition_id", "e_kin_j", "f_col_hz", "power_w"]]
        .to_dict(orient="records"),
        "noise_model": ("powder: a*E[kJ]+b + N(0, sigma_powder^2), sigma_powder from r2_target; "
                        "wax: linear ramp line(E1)->100 % at E2 + N(0, sigma_wax^2); complete: "
                        "100 - |N(0, sigma_complete^2)|; clipped to [0, 100]; phase = true regime"),
        "schedule_min": {str(k): list(v) for k, v in schedule.items()},
    }
    return cond, y, meta


#: the files :func:`write_yield_dataset` writes (an unmarked committed dataset folder holding
#: only these is its own earlier output)
DATASET_FILES = ("dataset.json", "conditions.csv", "yields.csv", "summary.csv")


def _is_generated(folder: Path) -> bool:
    """``folder`` holds a dataset written by :func:`generate_synthetic_yields` (its dataset.json
    says so): an earlier output of this module, not someone's measurements."""
    try:
        meta = json.loads((Path(folder) / "dataset.json").read_text())
    except (OSError, ValueError):
        return False
    return (isinstance(meta, dict) and meta.get("synthetic") is True
            and str(meta.get("source", "")).startswith(GENERATOR_SOURCE))


def _out_rule():
    return dict(area="datasets", own_names=DATASET_FILES, is_own=_is_generated)


def check_yield_out(out_dir, flag="--out") -> Path:
    """Raise :class:`analysis.atomic_dir.OutputError` unless ``out_dir`` is a folder a yield
    dataset may be written to: new, empty, marked as an earlier output of this project, or an
    unmarked dataset folder of the repository that this module's generator wrote (only its files,
    its dataset.json naming the generator)."""
    from analysis.atomic_dir import check_out_dir
    return check_out_dir(out_dir, flag=flag, **_out_rule())


def write_yield_dataset(out_dir: Path, conditions: pd.DataFrame, yields: pd.DataFrame,
                        meta: dict, summary: pd.DataFrame | None = None) -> Path:
    """Write dataset.json, conditions.csv, yields.csv (and summary.csv) atomically; a folder that
    is not ours to replace is refused (:func:`check_yield_out`)."""
    from analysis.atomic_dir import output_dir
    out_dir = Path(out_dir)
    with output_dir(out_dir, **_out_rule()) as tmp:
        (tmp / "dataset.json").write_text(json.dumps(meta, indent=1))
        conditions.to_csv(tmp / "conditions.csv", index=False)
        yields.to_csv(tmp / "yields.csv", index=False)
        if summary is not None:
            summary.to_csv(tmp / "summary.csv", index=False)
    return out_dir


def _summary_for(energy: pd.DataFrame) -> pd.DataFrame:
    """summary.csv of the synthetic dataset: the ASSUMED speeds/f_col (from Table 3), not data."""
    return pd.DataFrame({"condition_id": energy["condition_id"],
                         "v_mean_m_s": energy["v_mean_m_s"].round(5), "v_mean_sd_m_s": np.nan,
                         "f_col_hz": energy["f_col_hz"], "f_col_sd_hz": np.nan,
                         "note": "ASSUMED input of the SYNTHETIC yield generator "
                                 "(Table 3 interpolated to 20 mm), not a measurement"})


def main(argv=None) -> int:
    gen_example = ("example: python -m analysis.yield_data generate --out "
                   "data/measurements/synthetic_yields_paper --seed 0")
    check_example = ("example: python -m analysis.yield_data check "
                     "data/measurements/synthetic_yields_paper")
    p = argparse.ArgumentParser(prog="python -m analysis.yield_data",
                                description="Generate SYNTHETIC yield data or check a yield dataset.",
                                epilog=gen_example + "\n" + check_example,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    g = sub.add_parser("generate", help="write a SYNTHETIC dataset consistent with the paper",
                       epilog=gen_example)
    g.add_argument("--out", type=Path, default=SYNTHETIC_DATASET_DIR,
                   help="dataset folder to write (default: "
                        "data/measurements/synthetic_yields_paper)")
    g.add_argument("--seed", type=int, default=0,
                   help="random seed of the synthetic yields [-] (default %(default)s)")
    g.add_argument("--n-replicates", type=int, default=1,
                   help="samples per condition and milling time [samples] "
                        "(default %(default)s)")
    c = sub.add_parser("check", help="validate data/measurements/<name> (yields.csv)",
                       epilog=check_example)
    c.add_argument("path", type=Path, help="dataset folder data/measurements/<name>/")
    args = p.parse_args(argv)
    from analysis.atomic_dir import OutputError
    try:
        if args.cmd == "generate":
            check_yield_out(args.out)   # before any work
            energy = synthetic_energy_inputs(tuple(DEFAULT_SCHEDULE_MIN))
            cond, y, meta = generate_synthetic_yields(energy=energy, seed=args.seed,
                                                      n_replicates=args.n_replicates)
            out = write_yield_dataset(args.out, cond, y, meta, summary=_summary_for(energy))
            print(f"wrote SYNTHETIC yield dataset {out} ({len(y)} samples, seed {args.seed}, "
                  f"sigma_powder {meta['truth']['sigma_powder_pct']:.2f} %)")
        else:
            ds = load_yield_dataset(args.path)
            print(f"{ds.name}: {len(ds.conditions)} conditions, {len(ds.yields)} yield rows, "
                  f"synthetic={ds.synthetic}: OK")
    except (YieldDataError, kinetics.KineticsInputError, OutputError) as exc:
        print(f"analysis.yield_data: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
