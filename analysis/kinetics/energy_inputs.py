"""Energy inputs of the kinetics stage: E_kin and f_col per mill condition, and E_tot per
yield sample.

Until twin outputs exist the energy inputs come from the paper's Table 3 (measured v_mean of the
17.5 and 20.6 mm balls, linearly interpolated in diameter to the 20 mm ball of the yield
experiments; f_col measured = 2 f); :func:`load_twin_energy_table` reads twin outputs instead.
Every table carries a ``source`` column saying which it used.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from analysis import config
from analysis.kinetics.model import (STEEL_DENSITY_KG_M3, YIELD_BALL_DIAMETER_MM,
                                     KineticsInputError, cumulative_energy_j, kinetic_energy_j)

TABLE3_SOURCE_INTERP = ("paper Table 3 measured v_mean (17.5 and 20.6 mm balls) linearly "
                        "interpolated in ball diameter; f_col measured (= 2 f); NOT twin output")
TABLE3_SOURCE_AS_IS = ("paper Table 3 measured v_mean of the 20.6 mm ball used as is for the "
                       "requested ball; f_col measured (= 2 f); NOT twin output")


def _energy_frame(df: pd.DataFrame, density_kg_m3: float) -> pd.DataFrame:
    df = df.copy()
    df["e_kin_j"] = kinetic_energy_j(df["ball_diameter_m"].to_numpy(),
                                     df["v_mean_m_s"].to_numpy(), density_kg_m3)
    df["power_w"] = df["e_kin_j"] * df["f_col_hz"]
    return df


def table3_energy_inputs(ball_diameters_mm=(17.5, YIELD_BALL_DIAMETER_MM, 20.6),
                         assumption: str = "interp", table3_dir: Path | None = None,
                         density_kg_m3: float = STEEL_DENSITY_KG_M3) -> pd.DataFrame:
    """Energy inputs from the paper's Table 3 measurements (the stand-in for twin outputs).

    Parameters
    ----------
    ball_diameters_mm : sequence of float - balls to tabulate [mm]
    assumption : {"interp", "as_is"}
        "interp": v_mean linearly interpolated (or extrapolated) in diameter between the two
        measured balls (17.5, 20.6 mm) at each measured frequency. "as_is": the 20.6 mm ball's
        v_mean used for every requested diameter.
    table3_dir : Path, optional - dataset folder (default config.PAPER_TABLE3_DIR)

    Returns
    -------
    DataFrame, one row per (frequency, diameter): frequency_hz, ball_diameter_m, v_mean_m_s,
    f_col_hz, e_kin_j, power_w, measured (bool), source
    """
    if assumption not in ("interp", "as_is"):
        raise KineticsInputError(f"assumption must be 'interp' or 'as_is', got {assumption!r}")
    folder = Path(table3_dir) if table3_dir is not None else config.PAPER_TABLE3_DIR
    cond = pd.read_csv(folder / "conditions.csv")
    summ = pd.read_csv(folder / "summary.csv")
    t3 = cond.merge(summ, on="condition_id")
    rows = []
    for f_hz, grp in t3.groupby("frequency_hz"):
        grp = grp.sort_values("ball_diameter_mm")
        d_meas = grp["ball_diameter_mm"].to_numpy(float)
        v_meas = grp["v_mean_m_s"].to_numpy(float)
        fcol = float(grp["f_col_hz"].mean())
        for d_mm in ball_diameters_mm:
            measured = bool(np.any(np.isclose(d_meas, d_mm)))
            if measured:
                v = float(v_meas[np.isclose(d_meas, d_mm)][0])
                src = "paper Table 3 measured (NOT twin output)"
            elif assumption == "interp":
                slope = (v_meas[-1] - v_meas[0]) / (d_meas[-1] - d_meas[0])
                v = float(v_meas[0] + slope * (d_mm - d_meas[0]))
                src = TABLE3_SOURCE_INTERP
            else:
                v = float(v_meas[-1])
                src = TABLE3_SOURCE_AS_IS
            rows.append(dict(frequency_hz=float(f_hz), ball_diameter_m=d_mm * 1e-3,
                             v_mean_m_s=v, f_col_hz=fcol, measured=measured, source=src))
    return _energy_frame(pd.DataFrame(rows), density_kg_m3)


def load_twin_energy_table(path: Path, density_kg_m3: float = STEEL_DENSITY_KG_M3) -> pd.DataFrame:
    """Read a CSV of twin outputs and average replicate rows per (frequency, ball diameter).

    Parameters
    ----------
    path : Path - CSV with columns frequency_hz, ball_diameter_m, v_mean_m_s, f_col_hz
        (further columns are ignored)

    Returns
    -------
    DataFrame: frequency_hz, ball_diameter_m, v_mean_m_s, v_mean_sd_m_s, f_col_hz, n_runs,
    e_kin_j, power_w, measured (False), source
    """
    path = Path(path)
    if not path.is_file():
        raise KineticsInputError(f"{path}: twin table not found")
    try:
        df = pd.read_csv(path)
    except Exception as exc:  # malformed CSV
        raise KineticsInputError(f"{path}: cannot read CSV ({exc})") from exc
    need = ["frequency_hz", "ball_diameter_m", "v_mean_m_s", "f_col_hz"]
    for col in need:
        if col not in df.columns:
            raise KineticsInputError(f"{path}: missing column '{col}'")
    for col in need:
        vals = pd.to_numeric(df[col], errors="coerce")
        bad = np.flatnonzero(~np.isfinite(vals.to_numpy(float)))
        if bad.size:
            raise KineticsInputError(f"{path}: row {bad[0] + 2}, column '{col}': not a number")
        if col != "v_mean_m_s" and np.any(vals <= 0):
            row = int(np.flatnonzero(vals.to_numpy() <= 0)[0]) + 2
            raise KineticsInputError(f"{path}: row {row}, column '{col}': must be > 0")
        df[col] = vals.astype(float)
    if np.any(df["v_mean_m_s"] < 0):
        row = int(np.flatnonzero(df["v_mean_m_s"].to_numpy() < 0)[0]) + 2
        raise KineticsInputError(f"{path}: row {row}, column 'v_mean_m_s': must be >= 0")
    df["f_key"] = df["frequency_hz"].round(6)
    df["d_key"] = df["ball_diameter_m"].round(7)
    g = df.groupby(["f_key", "d_key"], sort=True)
    out = g.agg(frequency_hz=("frequency_hz", "mean"), ball_diameter_m=("ball_diameter_m", "mean"),
                v_mean_m_s=("v_mean_m_s", "mean"), v_mean_sd_m_s=("v_mean_m_s", "std"),
                f_col_hz=("f_col_hz", "mean"), n_runs=("v_mean_m_s", "size")).reset_index(drop=True)
    out["measured"] = False
    out["source"] = f"twin outputs ({path.name})"
    return _energy_frame(out, density_kg_m3)


def energy_for_conditions(conditions: pd.DataFrame, inputs: pd.DataFrame) -> pd.DataFrame:
    """Attach e_kin_j, f_col_hz, power_w and source to each yield condition.

    Parameters
    ----------
    conditions : DataFrame - condition_id, frequency_hz, ball_diameter_mm
    inputs : DataFrame - from :func:`table3_energy_inputs` or :func:`load_twin_energy_table`, or
        any table with frequency_hz, ball_diameter_m, v_mean_m_s, f_col_hz (e_kin_j and power_w
        are computed when absent)

    Raises
    ------
    KineticsInputError if a condition has no matching (frequency, diameter) row.
    """
    inputs = inputs.copy()
    if "e_kin_j" not in inputs.columns:
        inputs["e_kin_j"] = kinetic_energy_j(inputs["ball_diameter_m"].to_numpy(),
                                             inputs["v_mean_m_s"].to_numpy())
    inputs["power_w"] = inputs["e_kin_j"] * inputs["f_col_hz"]
    if "source" not in inputs.columns:
        inputs["source"] = "energy inputs (unlabelled)"
    rows = []
    for _, c in conditions.iterrows():
        m = inputs[np.isclose(inputs["frequency_hz"], c["frequency_hz"], atol=1e-6)
                   & np.isclose(inputs["ball_diameter_m"], c["ball_diameter_mm"] * 1e-3, atol=1e-6)]
        if m.empty:
            raise KineticsInputError(
                f"condition '{c['condition_id']}' ({c['frequency_hz']} Hz, "
                f"{c['ball_diameter_mm']} mm): no energy input (twin output) for it")
        r = m.iloc[0]
        rows.append(dict(condition_id=c["condition_id"], frequency_hz=float(c["frequency_hz"]),
                         ball_diameter_mm=float(c["ball_diameter_mm"]), v_mean_m_s=r["v_mean_m_s"],
                         e_kin_j=r["e_kin_j"], f_col_hz=r["f_col_hz"], power_w=r["power_w"],
                         source=r["source"]))
    return pd.DataFrame(rows)


def attach_cumulative_energy(yields: pd.DataFrame, energy: pd.DataFrame) -> pd.DataFrame:
    """yields (condition_id, time_min, yield_pct, ...) + energy per condition -> adds e_tot_j."""
    out = yields.merge(energy[["condition_id", "frequency_hz", "e_kin_j", "f_col_hz", "power_w"]],
                       on="condition_id", how="left", validate="many_to_one")
    if out["power_w"].isna().any():
        missing = sorted(out.loc[out["power_w"].isna(), "condition_id"].unique())
        raise KineticsInputError(f"no energy input for condition(s) {missing}")
    out["e_tot_j"] = cumulative_energy_j(out["e_kin_j"], out["f_col_hz"], out["time_min"] * 60.0)
    return out
