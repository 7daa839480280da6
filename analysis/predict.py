"""Predict PET yield for a new mill condition: surrogate (f, BVR) -> (v_mean, f_col), then
E_kin, E_tot and the kinetics fit -> yield with band and regime (paper Sections 4-5, Table 6,
Figure 14).

Function::

    predict(frequency_hz, ball_diameter_m, time_min, jar_volume_m3=25e-6, kind="lr")

CLI::

    python -m analysis.predict --frequency-hz 27.5 --ball-diameter-mm 20 --time-min 15 [--json]
    python -m analysis.predict --compare [--twin-table CSV]     # Table 6 / Figure 14

The surrogate comes from ``results/surrogate/surrogate.joblib`` (``python -m analysis.surrogate``);
when it is missing it is trained on the fly from ``--twin-table`` (or, failing that, from the
paper's Table 3 measurements, labelled as such). The kinetics fit comes from
``results/kinetics/kinetics_fit.json`` (``python -m analysis.kinetics``); when missing it is fitted
from the default yield dataset (the SYNTHETIC one until real yields exist). Every output carries
the source labels.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from analysis import config
from analysis import kinetics as kin
from analysis import surrogate as sur

DEFAULT_SURROGATE_PATH = config.SURROGATE_DIR / "surrogate.joblib"
DEFAULT_KINETICS_PATH = config.KINETICS_DIR / "kinetics_fit.json"
COMPARE_DIR = config.RESULTS_DIR / "predict"


class PredictInputError(ValueError):
    """Bad prediction input (negative time, times out of order, impossible geometry ...)."""


@dataclass
class Predictor:
    """A loaded surrogate bundle + kinetics fit; :meth:`query` is the fast path.

    Attributes
    ----------
    surrogate : analysis.surrogate.SurrogateBundle
    kinetics : analysis.kinetics.KineticsFit
    kind : str - surrogate kind used ('lr', 'rf' or 'gp')
    density_kg_m3 : float - ball density (steel)
    """

    surrogate: sur.SurrogateBundle
    kinetics: kin.KineticsFit
    kind: str = "lr"
    density_kg_m3: float = kin.STEEL_DENSITY_KG_M3

    def query(self, frequency_hz: float, ball_diameter_m: float, time_min,
              jar_volume_m3: float = sur.JAR_VOLUME_M3, alpha: float = 0.05) -> pd.DataFrame:
        """Yield prediction at one condition and one or more milling times.

        Parameters
        ----------
        frequency_hz : float - jar frequency [Hz], > 0
        ball_diameter_m : float - ball diameter [m], > 0
        time_min : float or ndarray, shape (m,) - milling times [min], >= 0, non-decreasing
        jar_volume_m3 : float - jar volume [m3] (BVR = ball volume / jar volume)

        Returns
        -------
        DataFrame, shape (m, ...): frequency_hz, ball_diameter_m, jar_volume_m3, bvr,
        v_mean_m_s, f_col_hz, e_kin_j, time_min, e_tot_j, yield_pct, ci_lo, ci_hi, pi_lo,
        pi_hi, regime, regime_uncertain, out_of_domain (+ v_mean_sd_m_s, f_col_sd_hz for 'gp')
        """
        _check_scalar("frequency_hz", frequency_hz)
        _check_scalar("ball_diameter_m", ball_diameter_m)
        _check_scalar("jar_volume_m3", jar_volume_m3)
        t = np.atleast_1d(np.asarray(time_min, dtype=float))
        if t.ndim != 1 or t.size == 0 or np.any(~np.isfinite(t)):
            raise PredictInputError("time_min must be one or more finite numbers")
        if np.any(t < 0):
            raise PredictInputError(f"time_min must be >= 0, got {t[t < 0][0]:g}")
        if np.any(np.diff(t) < 0):
            raise PredictInputError("time_min values must be in increasing order")
        try:
            s = self.surrogate.predict_arrays(frequency_hz, ball_diameter_m, jar_volume_m3,
                                              kind=self.kind)
        except sur.SurrogateInputError as exc:
            raise PredictInputError(str(exc)) from exc
        v = float(s["v_mean_m_s"][0])
        fcol = float(s["f_col_hz"][0])
        if v < 0 or fcol < 0:
            raise PredictInputError(f"surrogate returned a negative output (v {v:.3g} m/s, f_col "
                                    f"{fcol:.3g} Hz) - far outside its training domain")
        e_kin = 0.5 * float(kin.ball_mass_kg(ball_diameter_m, self.density_kg_m3)) * v * v
        e_tot = e_kin * fcol * t * 60.0
        cols = {"frequency_hz": float(frequency_hz), "ball_diameter_m": float(ball_diameter_m),
                "jar_volume_m3": float(jar_volume_m3), "bvr": float(s["bvr"][0]),
                "v_mean_m_s": v, "f_col_hz": fcol, "e_kin_j": e_kin}
        if "v_mean_sd_m_s" in s:
            cols["v_mean_sd_m_s"] = float(s["v_mean_sd_m_s"][0])
            cols["f_col_sd_hz"] = float(s["f_col_sd_hz"][0])
        cols = {k: np.full(t.shape, val) for k, val in cols.items()}
        cols.update(time_min=t, e_tot_j=e_tot)
        cols.update(kin.yield_bands(self.kinetics, e_tot, alpha))
        cols["out_of_domain"] = np.full(t.shape, bool(s["out_of_domain"][0]))
        return pd.DataFrame(cols)


def _check_scalar(name, value):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise PredictInputError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(v) or v <= 0:
        raise PredictInputError(f"{name} must be finite and > 0, got {value!r}")


def load_kinetics(path: Path | None = None, yields: Path | None = None) -> kin.KineticsFit:
    """The saved kinetics fit, or a fresh fit of the yield dataset when none is saved."""
    path = DEFAULT_KINETICS_PATH if path is None else Path(path)
    if path.is_file():
        return kin.KineticsFit.load(path)
    from analysis import yield_data

    ds = yield_data.load_yield_dataset(yields or yield_data.SYNTHETIC_DATASET_DIR)
    energy = kin.energy_for_conditions(ds.conditions, kin.table3_energy_inputs())
    data = kin.attach_cumulative_energy(ds.yields, energy)
    label = "SYNTHETIC yields" if ds.synthetic else f"yields: {ds.name}"
    return kin.fit_kinetics(data["e_tot_j"], data["yield_pct"], phase=data.get("phase"),
                            n_boot=200, source=f"{label}; energy: {energy['source'].iloc[0]}")


def load_surrogate(path: Path | None = None, twin_table: Path | None = None,
                   kinds=("lr",)) -> sur.SurrogateBundle:
    """The saved surrogate bundle, or one trained now from the twin table (Table 3 stand-in
    when no table is given). A bundle lacking a requested kind is retrained."""
    path = DEFAULT_SURROGATE_PATH if path is None else Path(path)
    if twin_table is None and path.is_file():
        b = sur.SurrogateBundle.load(path)
        if all(k in b.models for k in kinds):
            return b
    table = sur.load_twin_table(twin_table) if twin_table is not None else sur.table3_twin_table()
    return sur.fit_bundle(table, kinds=tuple(kinds))


def load_predictor(kind: str = "lr", surrogate_path=None, kinetics_path=None, twin_table=None,
                   yields=None) -> Predictor:
    """Predictor from saved artefacts (training / fitting what is missing)."""
    if kind not in sur.KINDS:
        raise PredictInputError(f"unknown surrogate kind {kind!r} (use one of {sur.KINDS})")
    return Predictor(surrogate=load_surrogate(surrogate_path, twin_table, kinds=(kind,)),
                     kinetics=load_kinetics(kinetics_path, yields), kind=kind)


def predict(frequency_hz: float, ball_diameter_m: float, time_min,
            jar_volume_m3: float = sur.JAR_VOLUME_M3, kind: str = "lr",
            predictor: Predictor | None = None) -> pd.DataFrame:
    """Yield prediction for one condition; see :meth:`Predictor.query` for the columns."""
    p = predictor if predictor is not None else load_predictor(kind)
    return p.query(frequency_hz, ball_diameter_m, time_min, jar_volume_m3)


# --------------------------------------------------------------------------------------------
# surrogate-to-yield comparison (paper Table 6 / Figure 14)
# --------------------------------------------------------------------------------------------
def compare_yield_sources(kinetics_fit: kin.KineticsFit, twin_energy: pd.DataFrame,
                          bundle: sur.SurrogateBundle, conditions: pd.DataFrame,
                          yields: pd.DataFrame | None = None, times_min=None,
                          kinds=None) -> pd.DataFrame:
    """Yields from twin outputs (DEM-MC) vs yields from surrogate outputs (SM-MC), and both vs
    measured yields when given.

    Parameters
    ----------
    kinetics_fit : KineticsFit
    twin_energy : DataFrame - frequency_hz, ball_diameter_m, v_mean_m_s, f_col_hz, e_kin_j
        (from :func:`analysis.kinetics.load_twin_energy_table` or the Table 3 stand-in)
    bundle : SurrogateBundle
    conditions : DataFrame - condition_id, frequency_hz, ball_diameter_mm
    yields : DataFrame, optional - condition_id, time_min, yield_pct (measured); its times are
        used when given, else ``times_min``
    kinds : list of str - surrogate kinds (default: all in the bundle)

    Returns
    -------
    DataFrame, one row per (condition, time): condition_id, frequency_hz, ball_diameter_mm,
    time_min, yield_measured_pct (if given), e_tot_twin_j, yield_twin_pct, e_tot_<kind>_j,
    yield_<kind>_pct,
    abs_err_<kind>_vs_twin_pct, and abs_err_<source>_vs_measured_pct
    """
    kinds = list(bundle.models) if kinds is None else list(kinds)
    energy = kin.energy_for_conditions(conditions, twin_energy)
    rows = []
    for _, c in energy.iterrows():
        if yields is not None:
            y = yields[yields["condition_id"] == c["condition_id"]]
            t, meas = y["time_min"].to_numpy(float), y["yield_pct"].to_numpy(float)
        else:
            t = np.asarray(times_min if times_min is not None else np.arange(0, 41, 5.0), float)
            meas = None
        twin = kin.predict_yield(kinetics_fit, c["e_kin_j"], c["f_col_hz"], t)
        df = pd.DataFrame({"condition_id": c["condition_id"], "frequency_hz": c["frequency_hz"],
                           "ball_diameter_mm": c["ball_diameter_mm"], "time_min": t})
        if meas is not None:
            df["yield_measured_pct"] = meas
        df["e_tot_twin_j"] = twin["e_tot_j"].to_numpy()
        df["yield_twin_pct"] = twin["yield_pct"].to_numpy()
        d_m = c["ball_diameter_mm"] * 1e-3
        for k in kinds:
            s = bundle.predict(c["frequency_hz"], d_m, kind=k)
            e_kin = kin.kinetic_energy_j(d_m, float(s["v_mean_m_s"].iloc[0]))
            p = kin.predict_yield(kinetics_fit, e_kin, float(s["f_col_hz"].iloc[0]), t)
            df[f"e_tot_{k}_j"] = p["e_tot_j"].to_numpy()
            df[f"yield_{k}_pct"] = p["yield_pct"].to_numpy()
            df[f"abs_err_{k}_vs_twin_pct"] = np.abs(df[f"yield_{k}_pct"] - df["yield_twin_pct"])
            df[f"out_of_domain_{k}"] = bool(s["out_of_domain"].iloc[0])
        if meas is not None:
            for src in ["twin"] + kinds:
                df[f"abs_err_{src}_vs_measured_pct"] = np.abs(df[f"yield_{src}_pct"] - meas)
        rows.append(df)
    return pd.concat(rows, ignore_index=True)


def summarize_comparison(table: pd.DataFrame) -> pd.DataFrame:
    """Table 6 style: mean absolute yield error per condition for each error column."""
    err = [c for c in table.columns if c.startswith("abs_err_")]
    return table.groupby(["condition_id", "frequency_hz"], sort=False)[err].mean().reset_index()


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------
def _parser():
    p = argparse.ArgumentParser(prog="python -m analysis.predict",
                                description="Predict PET yield for a mill condition via the "
                                            "surrogate and the kinetics fit.")
    p.add_argument("--frequency-hz", type=float)
    p.add_argument("--ball-diameter-mm", type=float)
    p.add_argument("--time-min", type=float, nargs="+")
    p.add_argument("--jar-volume-ml", type=float, default=25.0)
    p.add_argument("--model", choices=sur.KINDS, default="lr")
    p.add_argument("--surrogate", type=Path, default=None, help="surrogate bundle (.joblib)")
    p.add_argument("--kinetics", type=Path, default=None, help="kinetics_fit.json")
    p.add_argument("--twin-table", type=Path, default=None,
                   help="twin outputs CSV: trains the surrogate when no bundle exists; with "
                        "--compare also the DEM-MC (twin-output) yields")
    p.add_argument("--yields", type=Path, default=None, help="yield dataset for --compare")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--compare", action="store_true",
                   help="Table 6 / Figure 14: surrogate-based vs twin-based yields")
    p.add_argument("--out", type=Path, default=COMPARE_DIR)
    return p


def _run_compare(args) -> Path:
    from analysis import yield_data

    ds = yield_data.load_yield_dataset(args.yields or yield_data.SYNTHETIC_DATASET_DIR)
    kfit = load_kinetics(args.kinetics, args.yields)
    twin = (kin.load_twin_energy_table(args.twin_table) if args.twin_table is not None
            else kin.table3_energy_inputs())
    # the surrogates under test are the saved ones (trained on the design runs); --twin-table
    # here holds the twin's outputs at the compared conditions, never training data: training
    # on it would compare the twin with itself
    spath = Path(args.surrogate) if args.surrogate is not None else DEFAULT_SURROGATE_PATH
    bundle = (sur.SurrogateBundle.load(spath) if spath.is_file()
              else load_surrogate(None, None, kinds=sur.KINDS))
    table = compare_yield_sources(kfit, twin, bundle, ds.conditions, ds.yields)
    summ = summarize_comparison(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".tmp-predict-", dir=args.out.parent))
    try:
        table.to_csv(tmp / "yield_comparison.csv", index=False)
        summ.to_csv(tmp / "table6_abs_errors.csv", index=False)
        (tmp / "source.json").write_text(json.dumps(
            {"yields": "SYNTHETIC " + ds.name if ds.synthetic else ds.name,
             "twin_outputs": str(twin["source"].iloc[0]), "surrogate": bundle.source,
             "kinetics": kfit.source}, indent=1))
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from analysis.plotting import surrogate_plots as sp
        fig, axes = plt.subplots(1, 2, figsize=(8, 3.8))
        sp.plot_yield_parity(table, ax=axes[0], reference="yield_twin_pct",
                             kinds=list(bundle.models))
        axes[0].set_title("surrogate-MC vs twin-MC yield", fontsize=8)
        sp.plot_yield_parity(table, ax=axes[1], reference="yield_measured_pct",
                             kinds=["twin"] + list(bundle.models))
        axes[1].set_title(("SYNTHETIC " if ds.synthetic else "") + "measured vs predicted yield",
                          fontsize=8)
        fig.suptitle(("SYNTHETIC yields; " if ds.synthetic else "") + "twin outputs: "
                     + str(twin["source"].iloc[0])[:60] + "; surrogate: " + bundle.source[:40],
                     fontsize=7)
        fig.tight_layout(); fig.savefig(tmp / "fig14_yield_parity.png", dpi=120); plt.close(fig)
        if args.out.exists():
            shutil.rmtree(args.out)
        tmp.rename(args.out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    print(summ.to_string(index=False, float_format=lambda v: f"{v:.2f}"))
    print(f"wrote {args.out}")
    return args.out


def main(argv=None) -> int:
    p = _parser()
    args = p.parse_args(argv)
    try:
        if args.compare:
            _run_compare(args)
            return 0
        missing = [n for n in ("frequency_hz", "ball_diameter_mm", "time_min")
                   if getattr(args, n) is None]
        if missing:
            raise PredictInputError("missing " + ", ".join("--" + m.replace("_", "-") for m in missing))
        pred = load_predictor(args.model, args.surrogate, args.kinetics, args.twin_table, args.yields)
        out = pred.query(args.frequency_hz, args.ball_diameter_mm * 1e-3, args.time_min,
                         args.jar_volume_ml * 1e-6)
    except (PredictInputError, kin.KineticsInputError, sur.SurrogateInputError, ValueError,
            FileNotFoundError) as exc:
        print(f"predict: error: {exc}", file=sys.stderr)
        return 2
    sources = {"surrogate": f"{args.model}: {pred.surrogate.source}", "kinetics": pred.kinetics.source}
    if args.json:
        print(json.dumps({"sources": sources, "rows": json.loads(out.to_json(orient="records"))},
                         indent=1))
    else:
        r = out.iloc[0]
        print(f"f = {r['frequency_hz']:g} Hz, d = {r['ball_diameter_m'] * 1e3:g} mm, "
              f"jar {r['jar_volume_m3'] * 1e6:g} mL, BVR = {r['bvr']:.4f}"
              + ("   ** OUT OF SURROGATE DOMAIN **" if r["out_of_domain"] else ""))
        print(f"v_mean = {r['v_mean_m_s']:.3f} m/s, f_col = {r['f_col_hz']:.2f} Hz, "
              f"E_kin = {r['e_kin_j'] * 1e3:.2f} mJ")
        cols = ["time_min", "e_tot_j", "yield_pct", "ci_lo", "ci_hi", "pi_lo", "pi_hi", "regime",
                "regime_uncertain"]
        print(out[cols].to_string(index=False, float_format=lambda v: f"{v:.1f}"))
        print(f"sources: surrogate = {sources['surrogate']}; kinetics = {sources['kinetics']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
