"""Predict PET yield for a new mill condition: surrogate (f, BVR) -> (v_mean, f_col), then
E_kin, E_tot and the kinetics fit -> yield with band and regime (paper Sections 4-5, Table 6,
Figure 14).

Function::

    predict(frequency_hz, ball_diameter_m, time_min, jar_volume_m3=25e-6, kind="lr")

CLI::

    python -m analysis.predict --frequency-hz 27.5 --ball-diameter-mm 20 --time-min 15 [--json]
    python -m analysis.predict --frequency-hz 35 --ball-diameter-mm 20 --time-min 15 --extrapolate
    python -m analysis.predict --compare [--twin-table CSV]     # Table 6 / Figure 14

Inputs are checked before anything is loaded: frequency, ball diameter and jar volume finite and
> 0, times finite, >= 0 and in order, and the ball smaller than the twin's jar (measured from the
run config's default STL with the scene's own rule, :func:`geometry.stl_io.ball_fit_error`). A
condition outside the surrogates' training domain (the bundle's :class:`DomainCheck`: frequency and
BVR ranges and their convex hull) is refused with a message naming that domain, unless
``--extrapolate`` is given: then the answer is marked EXTRAPOLATED and its bands are the union of
the lr, rf and gp surrogates' bands (:meth:`Predictor.query_extrapolated`), so the models'
disagreement off the training data widens them.

The surrogate comes from ``results/surrogate/surrogate.joblib`` (``python -m analysis.surrogate``);
when it is missing it is trained on the fly from ``--twin-table`` (or, failing that, from the
paper's Table 3 measurements, labelled as such). The kinetics fit comes from
``results/kinetics/kinetics_fit.json`` (``python -m analysis.kinetics``); when missing it is fitted
from the default yield dataset (the SYNTHETIC one until real yields exist). Every output carries
the source labels.
"""
from __future__ import annotations

import argparse
import functools
import json
import sys
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


#: Surrogate kinds whose disagreement widens an extrapolated answer.
EXTRAPOLATION_KINDS = sur.KINDS


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
        ball_diameter_m : float - ball diameter [m], > 0 and smaller than the twin's jar
            (:func:`twin_jar`)
        time_min : float or ndarray, shape (m,) - milling times [min], >= 0, non-decreasing
        jar_volume_m3 : float - jar volume [m3] (BVR = ball volume / jar volume)

        A condition outside the surrogates' training domain is answered and flagged
        (out_of_domain); the CLI refuses it (:func:`domain_error`) unless asked to extrapolate
        (:meth:`query_extrapolated`).

        Returns
        -------
        DataFrame, shape (m, ...): frequency_hz, ball_diameter_m, jar_volume_m3, bvr,
        v_mean_m_s, f_col_hz, e_kin_j, time_min, e_tot_j, yield_pct, ci_lo, ci_hi, pi_lo,
        pi_hi, regime, regime_uncertain, out_of_domain (+ v_mean_sd_m_s, f_col_sd_hz for 'gp')
        """
        _check_scalar("frequency_hz", frequency_hz)
        _check_scalar("ball_diameter_m", ball_diameter_m)
        _check_scalar("jar_volume_m3", jar_volume_m3)
        t = _check_times("time_min", time_min)
        _check_ball_fits_jar(ball_diameter_m)
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

    def query_extrapolated(self, frequency_hz: float, ball_diameter_m: float, time_min,
                           jar_volume_m3: float = sur.JAR_VOLUME_M3,
                           alpha: float = 0.05) -> pd.DataFrame:
        """:meth:`query` with bands widened by the surrogates' disagreement (for a condition
        outside the training domain).

        Every kind of :data:`EXTRAPOLATION_KINDS` (lr, rf, gp) predicts (v_mean, f_col); each
        gives E_tot and yield bands through the same kinetics fit. The central values stay those
        of this predictor's kind; ci_lo / pi_lo become the smallest and ci_hi / pi_hi the largest
        over the kinds (the union of their bands, so never narrower than the single model's);
        regime_uncertain is also set where the kinds disagree on the regime.

        Returns
        -------
        DataFrame: the columns of :meth:`query` plus v_mean_spread_m_s, f_col_spread_hz,
        e_tot_lo_j, e_tot_hi_j, yield_spread_pct (max - min over the kinds) and
        extrapolated (True)

        Raises
        ------
        PredictInputError - the bundle lacks one of the kinds, or one of them predicts a
            negative speed or collision frequency
        """
        missing = [k for k in EXTRAPOLATION_KINDS if k not in self.surrogate.models]
        if missing:
            raise PredictInputError(
                "extrapolation needs the " + ", ".join(EXTRAPOLATION_KINDS) + " surrogates, the "
                f"bundle has {', '.join(self.surrogate.models)} (missing {', '.join(missing)}): "
                "train them with python -m analysis.surrogate")
        base = self.query(frequency_hz, ball_diameter_m, time_min, jar_volume_m3, alpha)
        t = base["time_min"].to_numpy(float)
        mass_kg = float(kin.ball_mass_kg(ball_diameter_m, self.density_kg_m3))
        v_k, f_k, e_k, bands = [], [], [], []
        for k in EXTRAPOLATION_KINDS:
            s = self.surrogate.predict_arrays(frequency_hz, ball_diameter_m, jar_volume_m3,
                                              kind=k)
            v, fcol = float(s["v_mean_m_s"][0]), float(s["f_col_hz"][0])
            if v < 0 or fcol < 0:
                raise PredictInputError(f"surrogate {k} returned a negative output (v {v:.3g} "
                                        f"m/s, f_col {fcol:.3g} Hz): too far outside its "
                                        "training domain to extrapolate")
            e_tot = 0.5 * mass_kg * v * v * fcol * t * 60.0
            v_k.append(v)
            f_k.append(fcol)
            e_k.append(e_tot)
            bands.append(kin.yield_bands(self.kinetics, e_tot, alpha))
        out = base.copy()
        for col, pick in (("ci_lo", np.minimum), ("pi_lo", np.minimum), ("ci_hi", np.maximum),
                          ("pi_hi", np.maximum)):
            out[col] = pick.reduce([out[col].to_numpy(float)] + [b[col] for b in bands])
        regimes = np.array([b["regime"] for b in bands], dtype=object)
        out["regime_uncertain"] = (out["regime_uncertain"].to_numpy(bool)
                                   | np.any([b["regime_uncertain"] for b in bands], axis=0)
                                   | np.any(regimes != out["regime"].to_numpy(object), axis=0))
        ys = np.array([b["yield_pct"] for b in bands])
        e = np.array(e_k)
        out["v_mean_spread_m_s"] = max(v_k) - min(v_k)
        out["f_col_spread_hz"] = max(f_k) - min(f_k)
        out["e_tot_lo_j"] = e.min(axis=0)
        out["e_tot_hi_j"] = e.max(axis=0)
        out["yield_spread_pct"] = ys.max(axis=0) - ys.min(axis=0)
        out["extrapolated"] = True
        return out


def _check_scalar(name, value, unit=""):
    """Raise PredictInputError unless ``value`` is a finite number > 0 (``name`` in the message)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise PredictInputError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(v) or v <= 0:
        raise PredictInputError(f"{name} must be finite and > 0{' [' + unit + ']' if unit else ''}"
                                f", got {v:g}")


def _check_times(name, time_min) -> np.ndarray:
    """Milling times as a 1-D array; PredictInputError unless finite, >= 0 and in order."""
    try:
        t = np.atleast_1d(np.asarray(time_min, dtype=float))
    except (TypeError, ValueError):
        raise PredictInputError(f"{name} must be one or more numbers, got {time_min!r}") from None
    if t.ndim != 1 or t.size == 0 or np.any(~np.isfinite(t)):
        raise PredictInputError(f"{name} must be one or more finite numbers"
                                + (f", got {t[~np.isfinite(t)][0]:g}"
                                   if t.ndim == 1 and np.any(~np.isfinite(t)) else ""))
    if np.any(t < 0):
        raise PredictInputError(f"{name} must be >= 0, got {t[t < 0][0]:g}")
    if np.any(np.diff(t) < 0):
        raise PredictInputError(f"{name} values must be in increasing order")
    return t


@functools.lru_cache(maxsize=1)
def twin_jar() -> tuple[str, dict]:
    """The jar the twin simulates by default: (stl_path as the run config names it, its
    measurements from :func:`geometry.stl_io.check_jar_mesh`, lengths in metres).

    The path and units are the run config's defaults (``yade_scripts/twin_config.py``), so this
    is the jar the surrogates' training runs used.
    """
    from geometry.stl_io import measure_jar

    cfg = config.twin_config.default_config()
    path = config.twin_config.resolve_stl(cfg, str(config.REPO_ROOT))
    return cfg["stl_path"], measure_jar(path, cfg["stl_units"])[1]


def _check_ball_fits_jar(ball_diameter_m, name="ball_diameter_m"):
    """PredictInputError when the ball cannot move in the twin's jar (the scene's own rule)."""
    from geometry.stl_io import ball_fit_error

    stl, info = twin_jar()
    problem = ball_fit_error(ball_diameter_m, info)
    if problem:
        raise PredictInputError(f"{name}: {problem} of {stl}")


def domain_error(bundle: sur.SurrogateBundle, frequency_hz: float, ball_diameter_m: float,
                 jar_volume_m3: float = sur.JAR_VOLUME_M3) -> str | None:
    """Why a condition lies outside the surrogates' training domain, or None when inside.

    The domain is the bundle's :class:`analysis.surrogate.DomainCheck` on (frequency_hz, bvr):
    both training ranges and their convex hull. The message names the offending input(s) and
    the domain as frequency [Hz] and ball diameter [mm] in the bundle's jar (from its BVR range).
    """
    b = float(sur.bvr(ball_diameter_m, jar_volume_m3))
    X = np.array([[float(frequency_hz), b]])
    in_range, in_hull = bundle.domain.check(X)
    if in_range[0] and in_hull[0]:
        return None
    dom = bundle.domain
    jar = bundle.jar_volume_m3
    d_lo, d_hi = ((6.0 * dom.min_[1] * jar / np.pi) ** (1 / 3),
                  (6.0 * dom.max_[1] * jar / np.pi) ** (1 / 3))
    ok_f, ok_b = bundle.domain.input_in_range(X)[0]
    what = []
    if not ok_f:
        what.append(f"frequency {float(frequency_hz):g} Hz")
    if not ok_b:
        what.append(f"ball {float(ball_diameter_m) * 1e3:g} mm (BVR {b:.4g})")
    where = (" and ".join(what) + " outside" if what else
             f"frequency {float(frequency_hz):g} Hz with ball {float(ball_diameter_m) * 1e3:g} "
             "mm: inside both ranges but outside the convex hull of")
    return (f"{where} the surrogates' training domain (frequency {dom.min_[0]:g}-"
            f"{dom.max_[0]:g} Hz, ball {d_lo * 1e3:.3g}-{d_hi * 1e3:.3g} mm in the "
            f"{jar * 1e6:g} mL jar, BVR {dom.min_[1]:.4g}-{dom.max_[1]:.4g}; trained on "
            f"{bundle.source})")


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
    p = argparse.ArgumentParser(
        prog="python -m analysis.predict",
        description="Predict PET yield for a mill condition via the surrogate and the kinetics "
                    "fit. Conditions outside the surrogates' training domain are refused unless "
                    "--extrapolate is given.",
        epilog="example: python -m analysis.predict --frequency-hz 27.5 --ball-diameter-mm 20 "
               "--time-min 5 15 30")
    p.add_argument("--frequency-hz", type=float, help="jar frequency [Hz], > 0")
    p.add_argument("--ball-diameter-mm", type=float,
                   help="ball diameter [mm], > 0 and smaller than the jar's inner diameter")
    p.add_argument("--time-min", type=float, nargs="+",
                   help="milling time(s) [min], >= 0, in increasing order")
    p.add_argument("--jar-volume-ml", type=float, default=25.0,
                   help="jar volume [mL] (BVR = ball volume / jar volume; default %(default)s)")
    p.add_argument("--extrapolate", action="store_true",
                   help="answer outside the surrogates' training domain too: marked "
                        "EXTRAPOLATED, with bands widened to the union of the lr, rf and gp "
                        "surrogates' bands (needs a bundle holding all three)")
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
    p.add_argument("--out", type=Path, default=COMPARE_DIR,
                   help="folder for --compare's tables and figure (default %(default)s)")
    return p


def _compare_inputs(args):
    """The files and folders ``--compare`` reads: never an output."""
    from analysis import yield_data
    return [args.yields if args.yields is not None else yield_data.SYNTHETIC_DATASET_DIR,
            args.kinetics if args.kinetics is not None else DEFAULT_KINETICS_PATH,
            args.surrogate if args.surrogate is not None else DEFAULT_SURROGATE_PATH,
            args.twin_table]


def _run_compare(args) -> Path:
    from analysis import yield_data
    from analysis.atomic_dir import check_out_dir, output_dir
    from analysis.plotting.surrogate_plots import write_yield_parity_figure

    protected = _compare_inputs(args)
    check_out_dir(args.out, protected)
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
    with output_dir(args.out, protected) as tmp:
        table.to_csv(tmp / "yield_comparison.csv", index=False)
        summ.to_csv(tmp / "table6_abs_errors.csv", index=False)
        (tmp / "source.json").write_text(json.dumps(
            {"yields": "SYNTHETIC " + ds.name if ds.synthetic else ds.name,
             "yields_synthetic": bool(ds.synthetic),
             "twin_outputs": str(twin["source"].iloc[0]), "surrogate": bundle.source,
             "kinetics": kfit.source}, indent=1))
        write_yield_parity_figure(table, tmp / "fig14_yield_parity.png", list(bundle.models),
                                  twin_source=str(twin["source"].iloc[0]),
                                  surrogate_source=bundle.source, synthetic=ds.synthetic)
    print(summ.to_string(index=False, float_format=lambda v: f"{v:.2f}"))
    print(f"wrote {args.out}")
    return args.out


def main(argv=None) -> int:
    p = _parser()
    args = p.parse_args(argv)
    try:
        if args.compare:
            from analysis.atomic_dir import check_out_dir
            check_out_dir(args.out, _compare_inputs(args))   # before any work
            _run_compare(args)
            return 0
        missing = [n for n in ("frequency_hz", "ball_diameter_mm", "time_min")
                   if getattr(args, n) is None]
        if missing:
            raise PredictInputError("missing " + ", ".join("--" + m.replace("_", "-") for m in missing))
        # impossible inputs are refused before anything is loaded, named as the user typed them
        _check_scalar("--frequency-hz", args.frequency_hz, "Hz")
        _check_scalar("--ball-diameter-mm", args.ball_diameter_mm, "mm")
        _check_scalar("--jar-volume-ml", args.jar_volume_ml, "mL")
        _check_times("--time-min", args.time_min)
        _check_ball_fits_jar(args.ball_diameter_mm * 1e-3, "--ball-diameter-mm")
        f_hz, d_m = args.frequency_hz, args.ball_diameter_mm * 1e-3
        jar_m3 = args.jar_volume_ml * 1e-6
        pred = load_predictor(args.model, args.surrogate, args.kinetics, args.twin_table, args.yields)
        outside = domain_error(pred.surrogate, f_hz, d_m, jar_m3)
        if outside is not None and not args.extrapolate:
            raise PredictInputError(outside + "; pass --extrapolate for an answer whose band is "
                                    "widened by the lr/rf/gp disagreement")
        if outside is None:
            out = pred.query(f_hz, d_m, args.time_min, jar_m3)
        else:
            out = pred.query_extrapolated(f_hz, d_m, args.time_min, jar_m3)
    except (PredictInputError, kin.KineticsInputError, sur.SurrogateInputError, ValueError,
            FileNotFoundError) as exc:
        print(f"analysis.predict: error: {exc}", file=sys.stderr)
        return 2
    sources = {"surrogate": f"{args.model}: {pred.surrogate.source}", "kinetics": pred.kinetics.source}
    extrapolation = None
    if outside is not None:
        extrapolation = (f"EXTRAPOLATED: {outside}; yield bands = union of the "
                         f"{', '.join(EXTRAPOLATION_KINDS)} surrogates' bands")
        print("analysis.predict: warning: answer EXTRAPOLATED outside the surrogates' training "
              "domain; its bands span the lr, rf and gp surrogates", file=sys.stderr)
    if args.json:
        doc = {"sources": sources, "rows": json.loads(out.to_json(orient="records"))}
        if extrapolation is not None:
            doc = {"EXTRAPOLATED": True, "extrapolation": extrapolation, **doc}
        print(json.dumps(doc, indent=1))
    else:
        r = out.iloc[0]
        print(f"f = {r['frequency_hz']:g} Hz, d = {r['ball_diameter_m'] * 1e3:g} mm, "
              f"jar {r['jar_volume_m3'] * 1e6:g} mL, BVR = {r['bvr']:.4f}"
              + ("   ** EXTRAPOLATED **" if extrapolation is not None
                 else "   ** OUT OF SURROGATE DOMAIN **" if r["out_of_domain"] else ""))
        print(f"v_mean = {r['v_mean_m_s']:.3f} m/s, f_col = {r['f_col_hz']:.2f} Hz, "
              f"E_kin = {r['e_kin_j'] * 1e3:.2f} mJ")
        if extrapolation is not None:
            print(extrapolation)
            print(f"surrogate spread ({'/'.join(EXTRAPOLATION_KINDS)}): v_mean "
                  f"{r['v_mean_spread_m_s']:.3f} m/s, f_col {r['f_col_spread_hz']:.2f} Hz")
        cols = ["time_min", "e_tot_j", "yield_pct", "ci_lo", "ci_hi", "pi_lo", "pi_hi", "regime",
                "regime_uncertain"]
        if extrapolation is not None:
            cols.insert(3, "yield_spread_pct")
        print(out[cols].to_string(index=False, float_format=lambda v: f"{v:.1f}"))
        print(f"sources: surrogate = {sources['surrogate']}; kinetics = {sources['kinetics']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
