"""Compare the twin with a measurement dataset: residuals, chi2, where and how it fails.

Input
-----
* a :class:`analysis.measurements.Dataset`;
* a predictions table (the twin's side), one row per condition and observable::

      condition_id, observable, mean, sd, n_replicates [, time_min]

  ``observable`` is a measured column name: ``v_mean_m_s``, ``f_col_hz`` or ``yield_pct`` (the
  latter with ``time_min``), or an impact observable of a track that carries the jar
  (``e_app``, ``v_in_m_s``, ``impact_phase_rad``, ``jar_amplitude_m``, ``vy_rms_m_s``: see
  :mod:`analysis.flights`; the measured side is read from the dataset's tracks, and its sigma
  also holds one twin run's sd, since a track is one realisation of the chaotic motion).
  ``mean`` and ``sd`` are the mean and the standard deviation OVER
  REPLICATE RUNS of the twin (runs that differ only in their seed / initial state), ``n_replicates``
  how many runs. The twin is chaotic: replicates scatter by 1-3 % in mean speed (DESIGN.md), as
  much as many physical effects move it, so the model's own noise enters every uncertainty.

Uncertainty of a residual
-------------------------
``residual = model_mean - measured`` and its standard uncertainty is::

    sigma = sqrt(measured_sd**2 + model_se**2),    model_se = model_sd / sqrt(n_replicates)

``measured_sd`` is the dataset's sd, or the documented default of
:func:`analysis.measurements.measurement_table` when the sd cell is empty (1.5 % of v, 1 /s for
f_col, 2 points for yields). When the twin gives no usable sd (n_replicates < 2 or sd empty) a
default per-replicate sd is used (2 % of v - the middle of the 1-3 % replicate scatter in
DESIGN.md -, 1 /s for f_col, 2 points for yields) and the row is flagged ``model_sd_default``.
``z = residual / sigma``; chi2 = sum z^2 over all compared rows, dof = rows - n_fitted_params.

CLI::

    python -m analysis.compare --dataset DIR --predictions CSV --out DIR [--model-tracks DIR]

writes comparison.csv, heatmap.png (condition x observable z), phase.png (when tracks exist on
both sides), yields.png (when yields exist) and comparison.md, atomically (temp folder, rename).
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.atomic_dir import output_dir
from analysis.report import comparison_page
from scipy import signal, stats

from analysis.flights import FLIGHT_OBSERVABLES, dataset_flights
from analysis.measurements import (DEFAULT_F_COL_SD_HZ, DEFAULT_V_REL_SD, DEFAULT_YIELD_SD_PCT,
                                   Dataset, DatasetError, load_dataset, measurement_table,
                                   yield_table)

#: default per-replicate sd of the twin when the predictions carry none
DEFAULT_MODEL_V_REL_SD = 0.02
DEFAULT_MODEL_F_COL_SD_HZ = 1.0
DEFAULT_MODEL_YIELD_SD_PCT = 2.0

#: plain-words names of observables
OBSERVABLE_WORDS = {"v_mean_m_s": "speed", "f_col_hz": "collision frequency",
                    "yield_pct": "yield", "e_app": "apparent restitution at the end walls",
                    "v_in_m_s": "approach speed at the end walls",
                    "impact_phase_rad": "jar phase at impact",
                    "jar_amplitude_m": "jar amplitude", "vy_rms_m_s": "vertical rms speed"}
#: impact observables (analysis.flights) are reported as differences in these units
#: (scale factor from SI, unit)
ABSOLUTE_UNITS = {"e_app": (1.0, ""), "v_in_m_s": (1.0, " m/s"), "impact_phase_rad": (1.0, " rad"),
                  "jar_amplitude_m": (1e3, " mm"), "vy_rms_m_s": (1e3, " mm/s")}

PREDICTION_COLUMNS = ("condition_id", "observable", "mean", "sd", "n_replicates")


class PredictionError(ValueError):
    """The predictions table is malformed (message names the row and column)."""


# --------------------------------------------------------------------------- result

@dataclass
class Comparison:
    """Result of :func:`compare`.

    Attributes
    ----------
    table : DataFrame, one row per compared (condition, observable[, time])
        condition_id, label, frequency_hz, ball_diameter_mm, observable, time_min, measured,
        measured_sd, measured_sd_default, model_mean, model_sd, n_replicates, model_se,
        model_sd_default, sigma, residual (model - measured, in the observable's unit),
        rel_residual_pct, z
    chi2 : float
    dof : int
    phase : DataFrame or None
        phase-folded velocity over the jar cycle, see :func:`phase_fold_compare`
    missing : list of (condition_id, observable)
        measured values with no prediction (not compared)
    """

    table: pd.DataFrame
    chi2: float
    dof: int
    phase: pd.DataFrame | None = None
    missing: tuple = ()

    @property
    def chi2_dof(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else float("nan")

    @property
    def p_value(self) -> float:
        """P(chi2_dof >= observed) if the model were right within the stated uncertainties."""
        return float(stats.chi2.sf(self.chi2, self.dof)) if self.dof > 0 else float("nan")

    @property
    def residuals(self) -> pd.Series:
        """Standardised residuals z indexed by (condition_id, observable)."""
        t = self.table
        return pd.Series(t["z"].to_numpy(), index=pd.MultiIndex.from_frame(
            t[["condition_id", "observable"]]), name="z")

    def to_frame(self) -> pd.DataFrame:
        """The per-row table (a copy)."""
        return self.table.copy()

    def chi2_by_observable(self) -> pd.DataFrame:
        """chi2, n and chi2/n per observable."""
        g = self.table.groupby("observable", sort=False)["z"]
        out = pd.DataFrame({"chi2": g.apply(lambda z: float(np.sum(z ** 2))), "n": g.size()})
        out["chi2_per_point"] = out["chi2"] / out["n"]
        return out

    def summary_lines(self, z_report: float = 2.0, max_lines: int = 12) -> list:
        """Plain-words lines for rows with |z| >= z_report, worst first.

        e.g. ``'20.6 mm ball at 22.5 Hz: speed 4.8 % high (3.1 sigma)'``.
        """
        t = self.table.loc[self.table["z"].abs() >= z_report]
        t = t.reindex(t["z"].abs().sort_values(ascending=False).index)
        lines = []
        for _, r in t.head(max_lines).iterrows():
            word = OBSERVABLE_WORDS.get(r["observable"], r["observable"])
            side = "high" if r["residual"] > 0 else "low"
            if r["observable"] == "yield_pct":
                lines.append("%s: %s at %g min %.1f points %s (%.1f sigma)"
                             % (r["label"], word, r["time_min"], abs(r["residual"]), side,
                                abs(r["z"])))
            elif r["observable"] in ABSOLUTE_UNITS:
                k, unit = ABSOLUTE_UNITS[r["observable"]]
                lines.append("%s: %s %.3g%s %s (%.1f sigma; measured %.3g%s)"
                             % (r["label"], word, k * abs(r["residual"]), unit, side,
                                abs(r["z"]), k * r["measured"], unit))
            else:
                lines.append("%s: %s %.1f %% %s (%.1f sigma)"
                             % (r["label"], word, abs(r["rel_residual_pct"]), side, abs(r["z"])))
        return lines

    def summary(self, z_report: float = 2.0) -> str:
        """Headline and the worst rows in plain words (model relative to measurement)."""
        n_out = int((self.table["z"].abs() >= z_report).sum())
        head = ("chi2/dof = %.2f over %d points (dof %d, p = %.2g); %d point(s) beyond %g sigma"
                % (self.chi2_dof, len(self.table), self.dof, self.p_value, n_out, z_report))
        lines = self.summary_lines(z_report)
        if not lines:
            lines = ["the model agrees with every measurement within %g sigma" % z_report]
        if self.missing:
            lines.append("%d measured value(s) had no prediction and were not compared"
                         % len(self.missing))
        return "\n".join([head] + ["- " + s for s in lines])


# --------------------------------------------------------------------------- predictions

def validate_predictions(pred: pd.DataFrame, condition_ids=None, fname="predictions") -> pd.DataFrame:
    """Check a predictions table; return a copy with numeric columns as float.

    Raises
    ------
    PredictionError : missing column, unknown condition_id, NaN mean, negative sd or
        n_replicates < 1, yield_pct row without time_min, duplicate key.
    """
    missing = [c for c in PREDICTION_COLUMNS if c not in pred.columns]
    if missing:
        raise PredictionError("%s: required column %r is missing (columns: %s)"
                              % (fname, missing[0], ", ".join(map(str, pred.columns))))
    p = pred.copy().reset_index(drop=True)
    p["condition_id"] = p["condition_id"].astype(str)
    if "time_min" not in p.columns:
        p["time_min"] = np.nan
    for col in ("mean", "sd", "n_replicates", "time_min"):
        try:
            p[col] = pd.to_numeric(p[col].replace("", np.nan)).astype(float)
        except (ValueError, TypeError):
            raise PredictionError("%s: column %r holds a non-number" % (fname, col)) from None
    for i, r in p.iterrows():
        where = "%s, row %d" % (fname, i + 1)
        if condition_ids is not None and r["condition_id"] not in condition_ids:
            raise PredictionError("%s, column 'condition_id': unknown condition_id %r"
                                  % (where, r["condition_id"]))
        if not np.isfinite(r["mean"]):
            raise PredictionError("%s, column 'mean': %r is not a finite number" % (where, r["mean"]))
        if np.isfinite(r["sd"]) and r["sd"] < 0:
            raise PredictionError("%s, column 'sd': negative sd %g" % (where, r["sd"]))
        if not np.isfinite(r["n_replicates"]) or r["n_replicates"] < 1:
            raise PredictionError("%s, column 'n_replicates': must be >= 1, got %r"
                                  % (where, r["n_replicates"]))
        if r["observable"] == "yield_pct" and not np.isfinite(r["time_min"]):
            raise PredictionError("%s, column 'time_min': yield_pct needs a time" % where)
    key = pd.Series(["%s | %s | %s" % (c, o, "" if not np.isfinite(t) else "%g min" % t)
                     for c, o, t in zip(p["condition_id"], p["observable"], p["time_min"])])
    dup = key.duplicated()
    if dup.any():
        i = int(np.nonzero(dup.to_numpy())[0][0])
        raise PredictionError("%s, row %d: duplicate prediction for %s" % (fname, i + 1, key[i]))
    return p


def _default_model_sd(obs, mean, v_rel, f_col_sd, yield_sd):
    if obs == "v_mean_m_s":
        return v_rel * abs(mean)
    if obs == "f_col_hz":
        return f_col_sd
    if obs == "yield_pct":
        return yield_sd
    return v_rel * abs(mean)


def model_standard_error(pred: pd.DataFrame, default_model_v_rel_sd=DEFAULT_MODEL_V_REL_SD,
                         default_model_f_col_sd_hz=DEFAULT_MODEL_F_COL_SD_HZ,
                         default_model_yield_sd_pct=DEFAULT_MODEL_YIELD_SD_PCT,
                         pool: bool = False) -> pd.DataFrame:
    """Add model_se (sd of the replicate mean) and model_sd_default to a predictions table.

    With ``pool`` the replicate sd of each observable is pooled over all conditions with
    n_replicates >= 2 (relative to the mean for v_mean_m_s, absolute otherwise; weights n - 1).
    A per-condition sd from 3 replicates has only 2 degrees of freedom, so z values built on it
    are heavy-tailed (Student t_2 in the limit of negligible measurement noise); pooling over 8
    conditions gives 16 dof. Do not pool when one condition's replicates are bimodal (a slow
    motion mode): that condition's scatter is real and its own.
    """
    p = pred.copy()
    sd = p["sd"].to_numpy(float).copy()
    n = p["n_replicates"].to_numpy(float)
    if pool:
        obs = p["observable"].to_numpy()
        mean = p["mean"].to_numpy(float)
        for o in np.unique(obs):
            m = (obs == o) & (n >= 2) & np.isfinite(sd)
            if not m.any():
                continue
            rel = o == "v_mean_m_s"
            x = sd[m] / np.abs(mean[m]) if rel else sd[m]
            pooled = math.sqrt(np.sum((n[m] - 1) * x ** 2) / np.sum(n[m] - 1))
            sd[m] = pooled * np.abs(mean[m]) if rel else pooled
    default = ~np.isfinite(sd) | (n < 2)
    for i in np.nonzero(default)[0]:
        if not np.isfinite(sd[i]) or sd[i] <= 0:
            sd[i] = _default_model_sd(p["observable"].iat[i], p["mean"].iat[i],
                                      default_model_v_rel_sd, default_model_f_col_sd_hz,
                                      default_model_yield_sd_pct)
        else:
            default[i] = False   # n == 1 but an sd from elsewhere was given: use it
    p["model_sd"] = sd
    p["model_se"] = sd / np.sqrt(n)
    p["model_sd_default"] = default
    return p


# --------------------------------------------------------------------------- compare

def compare(dataset: Dataset, predictions: pd.DataFrame, *, model_tracks: dict | None = None,
            v_rel_sd: float = DEFAULT_V_REL_SD, f_col_sd_hz: float = DEFAULT_F_COL_SD_HZ,
            yield_sd_pct: float = DEFAULT_YIELD_SD_PCT,
            default_model_v_rel_sd: float = DEFAULT_MODEL_V_REL_SD,
            default_model_f_col_sd_hz: float = DEFAULT_MODEL_F_COL_SD_HZ,
            default_model_yield_sd_pct: float = DEFAULT_MODEL_YIELD_SD_PCT,
            n_fitted_params: int = 0, n_phase_bins: int = 24,
            pool_model_sd: bool = False, flights: bool = True) -> Comparison:
    """Compare model predictions with a dataset, condition by condition.

    Parameters
    ----------
    dataset : Dataset
    predictions : DataFrame
        condition_id, observable, mean, sd, n_replicates [, time_min]; see module doc
    model_tracks : dict[str, DataFrame] or None
        condition_id -> the twin's track (t_s, x_m, y_m) in the dataset's ``velocity_frame``,
        for the phase-folded comparison (only conditions with a measured track are used)
    v_rel_sd, f_col_sd_hz, yield_sd_pct : float
        default measurement sd where the dataset gives none (fraction of v, 1/s, points)
    default_model_v_rel_sd, default_model_f_col_sd_hz, default_model_yield_sd_pct : float
        default per-replicate sd of the twin where predictions give none
    n_fitted_params : int
        parameters fitted to these same data (subtracted from dof)
    n_phase_bins : int
        bins over one jar cycle for the phase-folded comparison
    pool_model_sd : bool
        pool the twin's replicate sd per observable over conditions (see
        :func:`model_standard_error`); recommended with 3 replicates and no bimodal condition
    flights : bool
        when the predictions hold impact observables (``analysis.flights.FLIGHT_OBSERVABLES``:
        e_app, v_in_m_s, impact_phase_rad, jar_amplitude_m, vy_rms_m_s) and the dataset has
        tracks that carry the jar (``jar_x_m``), compare those too: measured by
        :func:`analysis.flights.dataset_flights`, their sigma also holding one twin run's sd
        (a track is one realisation)

    Returns
    -------
    Comparison
    """
    pred = validate_predictions(predictions, set(dataset.condition_ids))
    pred = model_standard_error(pred, default_model_v_rel_sd, default_model_f_col_sd_hz,
                                default_model_yield_sd_pct, pool=pool_model_sd)
    meas = measurement_table(dataset, v_rel_sd=v_rel_sd, f_col_sd_hz=f_col_sd_hz)
    meas["time_min"] = np.nan
    if dataset.yields is not None:
        y = yield_table(dataset, yield_sd_pct)    # the one rule for a missing yield sd
        meas = pd.concat([meas, pd.DataFrame({
            "condition_id": y["condition_id"].to_numpy(), "observable": "yield_pct",
            "value": y["value"].to_numpy(float), "sd": y["sd"].to_numpy(float),
            "sd_default": y["sd_default"].to_numpy(bool),
            "time_min": y["time_min"].to_numpy(float)})], ignore_index=True)
    meas["one_realisation"] = False
    if flights and pred["observable"].isin(FLIGHT_OBSERVABLES).any():
        fl = dataset_flights(dataset)            # tracks carrying the jar (analysis.flights)
        if len(fl):
            fl = fl.assign(sd_default=False, time_min=np.nan, one_realisation=True)
            meas = pd.concat([meas, fl], ignore_index=True)

    rows, missing = [], []
    cond = dataset.conditions.set_index("condition_id")
    summary_pred = pred.loc[pred["observable"] != "yield_pct"].set_index(
        ["condition_id", "observable"])
    for _, m in meas.iterrows():
        cid, obs = m["condition_id"], m["observable"]
        if obs == "yield_pct":
            pm = pred.loc[(pred["condition_id"] == cid) & (pred["observable"] == "yield_pct")]
            pm = pm.sort_values("time_min")
            tt = pm["time_min"].to_numpy(float)
            if len(pm) == 0 or not tt[0] <= m["time_min"] <= tt[-1]:
                missing.append((cid, obs, m["time_min"]))
                continue
            mean = float(np.interp(m["time_min"], tt, pm["mean"].to_numpy(float)))
            msd = float(np.interp(m["time_min"], tt, pm["model_sd"].to_numpy(float)))
            mse = float(np.interp(m["time_min"], tt, pm["model_se"].to_numpy(float)))
            nrep = float(pm["n_replicates"].min())
            mdef = bool(pm["model_sd_default"].any())
        else:
            if (cid, obs) not in summary_pred.index:
                missing.append((cid, obs))
                continue
            pr = summary_pred.loc[(cid, obs)]
            mean, msd, mse = float(pr["mean"]), float(pr["model_sd"]), float(pr["model_se"])
            nrep, mdef = float(pr["n_replicates"]), bool(pr["model_sd_default"])
        # an impact observable of one measured track is one realisation of the chaotic motion:
        # one run's scatter (model_sd) enters besides the record's own se
        sigma = math.sqrt(m["sd"] ** 2 + mse ** 2 + (msd ** 2 if m["one_realisation"] else 0.0))
        resid = mean - m["value"]
        rows.append({
            "condition_id": cid, "label": dataset.condition_label(cid),
            "frequency_hz": float(cond.at[cid, "frequency_hz"]),
            "ball_diameter_mm": float(cond.at[cid, "ball_diameter_mm"]),
            "observable": obs, "time_min": m["time_min"], "measured": m["value"],
            "measured_sd": m["sd"], "measured_sd_default": bool(m["sd_default"]),
            "model_mean": mean, "model_sd": msd, "n_replicates": nrep, "model_se": mse,
            "model_sd_default": mdef, "sigma": sigma, "residual": resid,
            "rel_residual_pct": (100.0 * resid / m["value"]
                                 if m["value"] != 0 and obs not in ABSOLUTE_UNITS else np.nan),
            "one_realisation": bool(m["one_realisation"]),
            "z": resid / sigma if sigma > 0 else np.nan})
    if not rows:
        raise PredictionError("predictions: no prediction matches a measured condition/observable")
    table = pd.DataFrame(rows)
    chi2 = float(np.nansum(table["z"].to_numpy() ** 2))
    dof = int(np.isfinite(table["z"]).sum()) - int(n_fitted_params)
    phase = None
    if model_tracks and dataset.tracks:
        phase = phase_fold_compare(dataset, model_tracks, n_bins=n_phase_bins)
    return Comparison(table=table, chi2=chi2, dof=dof, phase=phase, missing=tuple(missing))


# --------------------------------------------------------------------------- phase folding

def track_velocity(track: pd.DataFrame, smooth_s: float = 0.005) -> pd.DataFrame:
    """Velocity of a camera-plane track by Savitzky-Golay differentiation (as the paper did).

    Parameters
    ----------
    track : DataFrame, shape (n,) rows, t_s, x_m, y_m
    smooth_s : float
        Savitzky-Golay window [s] (cubic); for non-uniform sampling plain central differences

    Returns
    -------
    DataFrame : t_s, vx_m_s, vy_m_s, speed_m_s
    """
    t = track["t_s"].to_numpy(float)
    x = track["x_m"].to_numpy(float)
    y = track["y_m"].to_numpy(float)
    dt = np.diff(t)
    uniform = dt.size > 0 and np.allclose(dt, dt.mean(), rtol=1e-3)
    win = int(round(smooth_s / dt.mean())) | 1 if uniform else 0
    if uniform and 5 <= win < len(t):
        vx = signal.savgol_filter(x, win, 3, deriv=1, delta=dt.mean())
        vy = signal.savgol_filter(y, win, 3, deriv=1, delta=dt.mean())
    else:
        vx, vy = np.gradient(x, t), np.gradient(y, t)
    return pd.DataFrame({"t_s": t, "vx_m_s": vx, "vy_m_s": vy, "speed_m_s": np.hypot(vx, vy)})


def phase_fold(track: pd.DataFrame, frequency_hz: float, n_bins: int = 24,
               smooth_s: float = 0.005) -> pd.DataFrame:
    """Fold a track's velocity over the jar cycle (phase = frac(f t)).

    Returns
    -------
    DataFrame, shape (n_bins, 6)
        phase (bin centre, cycles), vx_mean_m_s, vx_sd_m_s, speed_mean_m_s, speed_sd_m_s, n
    """
    v = track_velocity(track, smooth_s)
    ph = np.mod(v["t_s"].to_numpy() * frequency_hz, 1.0)
    b = np.minimum((ph * n_bins).astype(int), n_bins - 1)
    df = pd.DataFrame({"b": b, "vx": v["vx_m_s"], "sp": v["speed_m_s"]})
    g = df.groupby("b")
    out = pd.DataFrame({"phase": (np.arange(n_bins) + 0.5) / n_bins})
    out["vx_mean_m_s"] = g["vx"].mean().reindex(range(n_bins)).to_numpy()
    out["vx_sd_m_s"] = g["vx"].std().reindex(range(n_bins)).to_numpy()
    out["speed_mean_m_s"] = g["sp"].mean().reindex(range(n_bins)).to_numpy()
    out["speed_sd_m_s"] = g["sp"].std().reindex(range(n_bins)).to_numpy()
    out["n"] = g.size().reindex(range(n_bins)).fillna(0).astype(int).to_numpy()
    return out


def phase_fold_compare(dataset: Dataset, model_tracks: dict, n_bins: int = 24,
                       align: bool = True) -> pd.DataFrame:
    """Phase-folded velocity of model and measurement for every condition with both tracks.

    The measured clock has no known jar phase, so with ``align`` the measured folded curve is
    shifted circularly (whole bins) to best match the model's vx curve; the shift is reported.

    Returns
    -------
    DataFrame
        condition_id, label, phase, side ('measured' | 'model'), vx_mean_m_s, vx_sd_m_s,
        speed_mean_m_s, speed_sd_m_s, n, shift_bins
    """
    cond = dataset.conditions.set_index("condition_id")
    parts = []
    for cid, mtrack in dataset.tracks.items():
        if cid not in model_tracks:
            continue
        f = float(cond.at[cid, "frequency_hz"])
        fm = phase_fold(mtrack, f, n_bins)
        fp = phase_fold(model_tracks[cid], f, n_bins)
        shift = 0
        if align:
            a = np.nan_to_num(fm["vx_mean_m_s"].to_numpy())
            b = np.nan_to_num(fp["vx_mean_m_s"].to_numpy())
            shift = int(np.argmin([np.sum((np.roll(a, k) - b) ** 2) for k in range(n_bins)]))
            for col in ("vx_mean_m_s", "vx_sd_m_s", "speed_mean_m_s", "speed_sd_m_s", "n"):
                fm[col] = np.roll(fm[col].to_numpy(), shift)
        for side, fr in (("measured", fm), ("model", fp)):
            fr = fr.copy()
            fr.insert(0, "side", side)
            fr.insert(0, "label", dataset.condition_label(cid))
            fr.insert(0, "condition_id", cid)
            fr["shift_bins"] = shift
            parts.append(fr)
    return pd.concat(parts, ignore_index=True) if parts else None


# --------------------------------------------------------------------------- report / CLI

#: the comparison.md text (:func:`analysis.report.comparison_page`), under its former name
markdown_page = comparison_page


def write_report(cmp: Comparison, dataset: Dataset, out_dir, overwrite: bool = True) -> Path:
    """Write comparison.csv, figures and comparison.md into ``out_dir`` atomically; an
    ``out_dir`` that is not ours to replace, or is / holds / lies in the dataset, is refused."""
    from analysis.plotting.compare_plots import write_compare_figures

    out_dir = Path(out_dir)
    protected = [dataset.path] if dataset.path is not None else []
    with output_dir(out_dir, protected) as tmp:
        cmp.to_frame().to_csv(tmp / "comparison.csv", index=False)
        figs = write_compare_figures(cmp, dataset, tmp)
        (tmp / "comparison.md").write_text(comparison_page(cmp, dataset, figs))
        if out_dir.exists() and not overwrite:
            raise FileExistsError(out_dir)
    return out_dir


def _read_model_tracks(folder):
    tracks = {}
    for f in sorted(Path(folder).glob("*.csv")):
        df = pd.read_csv(f)
        for c in ("t_s", "x_m", "y_m"):
            if c not in df.columns:
                raise PredictionError("%s: required column %r is missing" % (f, c))
        tracks[f.stem] = df
    return tracks


def main(argv=None):
    ap = argparse.ArgumentParser(description="Compare twin predictions with a measurement "
                                 "dataset (residuals, chi2/dof, heat map, Markdown page).",
                                 epilog="example: python -m analysis.compare --dataset "
                                 "data/measurements/paper_table3 --predictions "
                                 "twin_predictions.csv --out results/compare/paper_table3 "
                                 "(twin_predictions.csv: the twin's means over seeds, columns "
                                 "as --predictions says)")
    ap.add_argument("--dataset", required=True, help="dataset folder data/measurements/<name>/")
    ap.add_argument("--predictions", required=True,
                    help="CSV: condition_id, observable, mean, sd, n_replicates [, time_min]")
    ap.add_argument("--out", required=True, help="output folder (replaced atomically)")
    ap.add_argument("--model-tracks", help="folder of the twin's tracks <condition_id>.csv")
    ap.add_argument("--v-rel-sd", type=float, default=DEFAULT_V_REL_SD,
                    help="measured v sd where missing, fraction of v [-] (default %(default)s)")
    ap.add_argument("--f-col-sd-hz", type=float, default=DEFAULT_F_COL_SD_HZ,
                    help="measured f_col sd where missing [1/s] (default %(default)s)")
    ap.add_argument("--pool-model-sd", action="store_true",
                    help="pool the twin's replicate sd per observable over conditions")
    ap.add_argument("--z-report", type=float, default=2.0,
                    help="|z| from which a residual is listed in the summary [-] (standard "
                    "uncertainties; default %(default)s)")
    args = ap.parse_args(argv)
    from analysis.atomic_dir import OutputError, check_out_dir
    try:
        check_out_dir(args.out, [args.dataset])
        ds = load_dataset(args.dataset)
        try:
            pred = pd.read_csv(args.predictions)
        except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
            raise PredictionError("%s: cannot read (%s)" % (args.predictions, exc)) from None
        tracks = _read_model_tracks(args.model_tracks) if args.model_tracks else None
        try:
            cmp = compare(ds, pred, model_tracks=tracks, v_rel_sd=args.v_rel_sd,
                          f_col_sd_hz=args.f_col_sd_hz, pool_model_sd=args.pool_model_sd)
        except PredictionError as exc:
            raise PredictionError("%s: %s" % (args.predictions, exc)) from None
        write_report(cmp, ds, args.out)
    except (DatasetError, PredictionError, OutputError) as exc:
        print("error: %s" % exc, file=sys.stderr)
        return 2
    print(cmp.summary(args.z_report))
    print("wrote %s" % args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
