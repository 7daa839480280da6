"""The twin as a model for :mod:`analysis.diagnose`: which catalog effect is missing?

diagnose needs a ``predict(theta_base, effects)`` that it can call a few hundred times; one twin
run costs ~20 s, so the whole catalog on 8 conditions cannot be run inside a fit. The model here is
an emulator assembled from real twin runs, each part justified by what the twin does:

* **anchor**: the twin at the reference parameters ``theta_ref`` (the issue-4 calibration's
  posterior mean), every effect off, 4 seeds per condition (2 were too few: f_col has heavy
  tails - both of two seeds chattered at 30 Hz, 20.6 mm) - its per-condition means
  carry the twin's own structure (ball-size dependence, f_col quantisation) exactly;
* **base parameters** (restitution C_R and jar amplitude A by default): the change from
  ``theta_ref`` is the GP emulator of the calibration (:mod:`analysis.emulator`, trained on the
  calibration's 56 twin runs, leave-one-out error 0.75 % on v_mean), used only as a *difference*
  GP(theta) - GP(theta_ref), so its bias at ``theta_ref`` cancels. Static and rolling friction
  are held at ``theta_ref``: the calibration posterior spans half of their prior ranges, i.e.
  v_mean barely depends on them, and a GP slope fitted from 7 parameter sets there is noise;
* **DEM effects**: the *signature library* - the twin at ``theta_ref`` with one effect at its
  signature strength (the top of its diagnose range), same seeds as the anchor; the change of
  each observable is interpolated linearly in the effect's strength coordinate (chosen per effect
  so that the response is close to linear: the restitution drop k, the arm curvature, (f_0/f_n)^2
  for the mount's stiffness, h^2 for the powder layer's absorbed energy, the extra rolling
  friction, the drag multiplier). Effects add;
* **kinetics**: yields from the predicted E_kin = m v^2 / 2 and f_col through the powder line
  X = a E_tot + b (a, b base parameters) or a kinetics effect's ``modify_kinetics``; exact.

The model's own noise (``model_se``) is the anchor's replicate standard error (pooled relative
sd over the conditions); the signatures carry the same noise on both sides of the difference, so
diagnose is told ``crn_correlation = 0`` and its identifiability gate subtracts that noise from
every footprint: an effect the twin cannot tell from its chaos (air drag, the decoy) is never
identifiable.

    python -m analysis.twin_model --build [--replicates 2] [--workers 2]   # the library
    python -m analysis.diagnose --dataset DIR --model analysis.twin_model:factory --out DIR
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.config import PAPER_TABLE3_DIR, RESULTS_DIR

SIGNATURE_DIR = RESULTS_DIR / "signatures"
CALIBRATION_DIR = RESULTS_DIR / "calibration"
OUTPUTS = ("v_mean_m_s", "f_col_hz")
STEEL_DENSITY_KG_M3 = 7800.0  # analysis.kinetics.STEEL_DENSITY_KG_M3 (checked in the tests)
V_REL_SD_FLOOR = 0.0025       # smallest replicate sd of one run's v_mean (relative)
F_COL_SD_FLOOR_HZ = 1.0       # smallest replicate sd of one run's f_col [1/s]


@dataclass(frozen=True)
class Candidate:
    """One catalog effect as a diagnose candidate.

    name : effect module name
    kind : 'dem' or 'kinetics'
    param : the catalog parameter the strength sets
    s_max : top of the diagnose range of the strength coordinate (the signature strength of a
        DEM effect)
    unit : unit of the strength coordinate
    coord : 'linear' (strength = param), 'inv_square' (strength = (p0 / param)^2) or
        'square' (strength = (param / p0)^2)
    p0 : reference of the non-linear coordinates
    fixed : further parameters of the effect (defaults otherwise)
    """

    name: str
    kind: str
    param: str
    s_max: float
    unit: str
    coord: str = "linear"
    p0: float = 1.0
    fixed: tuple = ()

    def param_value(self, s):
        """Catalog parameter value for strength ``s`` (> 0)."""
        if self.coord == "linear":
            return float(s)
        if self.coord == "inv_square":
            return float(self.p0 / math.sqrt(s))
        if self.coord == "square":
            return float(self.p0 * math.sqrt(s))
        raise ValueError("unknown strength coordinate %r" % self.coord)

    def strength_of(self, value):
        """Strength coordinate of a catalog parameter value."""
        if self.coord == "linear":
            return float(value)
        if self.coord == "inv_square":
            return float((self.p0 / value) ** 2)
        return float((value / self.p0) ** 2)

    def spec(self, s):
        """The effects-config entry {name: {param: value, ...}} at strength ``s`` > 0."""
        return {self.name: dict(dict(self.fixed), **{self.param: self.param_value(s)})}

    @property
    def strength_label(self):
        if self.coord == "linear":
            return "%s [%s]" % (self.param, self.unit)
        if self.coord == "inv_square":
            return "(%g %s / %s)^2" % (self.p0, self.unit, self.param)
        return "(%s / %g %s)^2" % (self.param, self.p0, self.unit)


# The diagnose ranges: physically plausible, and wide enough that the top moves v_mean by a few
# per cent (signature strengths; the pilot figures are in results/signatures/README.md).
CANDIDATES = (
    Candidate("viscoelastic_restitution", "dem", "k", 0.6, "-"),
    Candidate("arc_motion", "dem", "curvature_1_m", 15.0, "1/m"),
    Candidate("jar_compliance", "dem", "f_n_hz", 1.5, "Hz", coord="inv_square", p0=100.0),
    Candidate("powder_layer", "dem", "layer_thickness_m", 1.0, "m", coord="square",
              p0=5e-4),
    Candidate("rolling_resistance", "dem", "extra_rolling_friction", 2.0, "-"),
    Candidate("air_drag", "dem", "drag_scale", 1.0, "-"),
    Candidate("impact_threshold", "kinetics", "threshold_energy_j", 0.04, "J"),
    Candidate("first_order_depletion", "kinetics", "depletion", 1.0, "-"),
    Candidate("induction_period", "kinetics", "induction_energy_j", 1500.0, "J"),
    Candidate("temperature_rise", "kinetics", "thermal_resistance_k_w", 1.0, "K/W"),
)
DECOYS = ("air_drag",)


def candidates(kind=None):
    """The candidates of one kind ('dem', 'kinetics') or all, by name."""
    return {c.name: c for c in CANDIDATES if kind is None or c.kind == kind}


def reference_parameters(calibration_dir=CALIBRATION_DIR):
    """theta_ref: the calibration's posterior mean (restitution, static_friction,
    rolling_friction, amplitude_m), rounded to 4 significant digits (stable run ids)."""
    p = Path(calibration_dir) / "summary.json"
    if not p.exists():
        raise FileNotFoundError("%s missing: run the calibration first (make calibrate)" % p)
    params = json.loads(p.read_text())["params"]
    return {k: float("%.4g" % v) for k, v in params.items()}


# --------------------------------------------------------------------------- the library

def library_configs(conditions, theta_ref, replicates=2, seed0=0, base=None,
                    anchor_replicates=None):
    """(label, effect, strength, condition_id, config) rows of the signature library: the anchor
    (label 'none', ``anchor_replicates`` seeds, default ``replicates``) and every DEM candidate
    at its signature strength (the first ``replicates`` of the same seeds)."""
    rows = []
    variants = [("none", None, 0.0, None)]
    variants += [(c.name, c.name, c.s_max, c.spec(c.s_max)) for c in CANDIDATES
                 if c.kind == "dem"]
    for label, eff, s, spec in variants:
        n_seeds = (anchor_replicates or replicates) if label == "none" else replicates
        for cnd in conditions.itertuples():
            for k in range(n_seeds):
                cfg = dict(base or {}, **theta_ref)
                cfg.update(frequency_hz=float(cnd.frequency_hz),
                           ball_diameter_m=float(cnd.ball_diameter_mm) * 1e-3,
                           seed=seed0 + k)
                if spec:
                    cfg["effects"] = spec
                rows.append((label, eff, s, cnd.condition_id, cfg))
    return rows


def summarise_library(runs: pd.DataFrame) -> pd.DataFrame:
    """Per (label, condition): mean, sd and n of v_mean and f_col, and the change from the anchor
    (dv_pct, its se assuming independent replicates)."""
    g = runs.groupby(["label", "condition_id"], sort=False)
    s = g.agg(strength=("strength", "first"), n=("v_mean_m_s", "size"),
              v_mean_m_s=("v_mean_m_s", "mean"), v_sd_m_s=("v_mean_m_s", "std"),
              f_col_hz=("f_col_hz", "mean"), f_col_sd_hz=("f_col_hz", "std")).reset_index()
    a = s[s["label"] == "none"].set_index("condition_id")
    s["dv_pct"] = 100 * (s["v_mean_m_s"] / a.loc[s["condition_id"], "v_mean_m_s"].to_numpy() - 1)
    s["df_col_hz"] = s["f_col_hz"] - a.loc[s["condition_id"], "f_col_hz"].to_numpy()
    return s


def build_library(out_dir=SIGNATURE_DIR, replicates=2, workers=2, runs_dir=None, runner=None,
                  conditions=None, theta_ref=None, base=None, anchor_replicates=4):
    """Run (cached) and write the signature library: signature_runs.csv, signatures.csv,
    signatures.png, library.json. Returns the summary table."""
    from analysis.atomic_dir import publish_dir, staging_dir
    from analysis.measurements import load_dataset
    from analysis.sweep import run_sweep
    import shutil

    if conditions is None:
        conditions = load_dataset(PAPER_TABLE3_DIR).conditions
    theta_ref = dict(theta_ref or reference_parameters())
    rows = library_configs(conditions, theta_ref, replicates=replicates, base=base,
                           anchor_replicates=max(anchor_replicates or 0, replicates))
    res = run_sweep([r[4] for r in rows], runner=runner, workers=workers, runs_dir=runs_dir)
    if not res.ok:
        raise RuntimeError("signature library: %d twin run(s) failed:\n%s"
                           % (res.n_failed, res.failed()[["run_id", "error"]].to_string()))
    t = res.table.reset_index(drop=True)
    runs = pd.DataFrame({"label": [r[0] for r in rows], "strength": [r[2] for r in rows],
                         "condition_id": [r[3] for r in rows],
                         "seed": [r[4]["seed"] for r in rows]})
    for c in ("frequency_hz", "ball_diameter_m", "v_mean_m_s", "f_col_hz", "motion_mode",
              "run_id"):
        if c in t.columns:
            runs[c] = t[c].to_numpy()
    summ = summarise_library(runs)
    out_dir = Path(out_dir)
    tmp = staging_dir(out_dir)
    try:
        runs.to_csv(tmp / "signature_runs.csv", index=False)
        summ.to_csv(tmp / "signatures.csv", index=False)
        meta = {"theta_ref": theta_ref, "replicates": replicates,
                "anchor_replicates": max(anchor_replicates or 0, replicates),
                "base_config": base or {},
                "candidates": [c.__dict__ | {"fixed": dict(c.fixed)} for c in CANDIDATES],
                "conditions": conditions[["condition_id", "frequency_hz",
                                          "ball_diameter_mm"]].to_dict("records")}
        (tmp / "library.json").write_text(json.dumps(meta, indent=1))
        plot_library(summ, tmp / "signatures.png")
        write_page(summ, meta, tmp)
        publish_dir(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return summ


def plot_library(summ, path):
    """Bar chart: change of v_mean [%] per condition for every DEM effect at its signature
    strength, with the anchor's +-2 se band."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    labels = [c for c in summ["label"].unique() if c != "none"]
    cids = list(summ.loc[summ["label"] == "none", "condition_id"])
    a = summ[summ["label"] == "none"].set_index("condition_id")
    rel_se = float(np.nanmean(a["v_sd_m_s"] / a["v_mean_m_s"])) / math.sqrt(a["n"].mean())
    fig, ax = plt.subplots(figsize=(9, 4))
    w = 0.8 / max(len(labels), 1)
    x = np.arange(len(cids))
    for i, lab in enumerate(labels):
        d = summ[summ["label"] == lab].set_index("condition_id").loc[cids]
        ax.bar(x + (i - (len(labels) - 1) / 2) * w, d["dv_pct"], w, label=lab)
    band = 2 * 100 * rel_se * math.sqrt(2)
    ax.axhspan(-band, band, color="0.85", zorder=0, label="+-2 se of a difference")
    ax.set_xticks(x, cids, rotation=30, ha="right")
    ax.set_ylabel("change of v_mean [%]")
    ax.set_title("Effect signatures at the calibrated parameters (signature strengths)")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_page(summ, meta, folder):
    """README.md of the library: what it is, the signatures table, the figure."""
    cands = {c["name"]: c for c in meta["candidates"]}
    a = summ[summ["label"] == "none"]
    rel = 100 * float(np.sqrt(np.nanmean((a["v_sd_m_s"] / a["v_mean_m_s"]) ** 2)))
    piv = summ.pivot(index="condition_id", columns="label", values="dv_pct")
    piv = piv.loc[list(a["condition_id"]), [c for c in piv.columns if c != "none"]]
    lines = ["# Effect signatures of the twin", "",
             "The twin at the calibrated parameters %s, every DEM catalog effect at the top of "
             "its diagnose range, %d seeds per condition (the same seeds as the anchor without "
             "effects). Regenerate with `make signatures` (`analysis/twin_model.py`); used by "
             "`analysis.twin_model.TwinModel` (diagnose's model), the hidden-effect suite and "
             "`make hidden-demo`." % (meta["theta_ref"], meta["replicates"]), "",
             "Replicate scatter of one run's v_mean at the anchor: %.2f %% (pooled over the "
             "conditions); a difference of two %d-seed means has a standard error of %.2f %%."
             % (rel, meta["replicates"], rel * math.sqrt(2.0 / meta["replicates"])), "",
             "Change of v_mean [%] against the anchor:", "",
             "| condition | " + " | ".join("%s (%s = %g)" % (
                 c, cands[c]["param"], Candidate(**dict(cands[c], fixed=())).param_value(
                     cands[c]["s_max"])) for c in piv.columns) + " |",
             "|---|" + "---|" * len(piv.columns)]
    for cid, r in piv.iterrows():
        lines.append("| %s | " % cid + " | ".join("%+.2f" % v for v in r) + " |")
    df = summ.pivot(index="condition_id", columns="label", values="df_col_hz")
    lines += ["", "Change of f_col [1/s] (a 0.5 s record counts in steps of 2 /s):", "",
              "| condition | " + " | ".join(piv.columns) + " |", "|---|" + "---|" * len(piv.columns)]
    for cid in piv.index:
        lines.append("| %s | " % cid + " | ".join("%+.1f" % df.loc[cid, c] for c in piv.columns)
                     + " |")
    lines += ["", "![signatures](signatures.png)", ""]
    (Path(folder) / "README.md").write_text("\n".join(lines))


def load_library(lib_dir=SIGNATURE_DIR):
    """(summary table, library.json dict) of a built signature library."""
    lib_dir = Path(lib_dir)
    f = lib_dir / "signatures.csv"
    if not f.exists():
        raise FileNotFoundError("signature library %s missing: run `make signatures`" % f)
    return pd.read_csv(f), json.loads((lib_dir / "library.json").read_text())


# --------------------------------------------------------------------------- the model

def base_emulator(calibration_dir=CALIBRATION_DIR, random_state=0):
    """The calibration's GP emulator refitted on its design runs (results/calibration)."""
    from analysis.emulator import GPEmulator
    d = pd.read_csv(Path(calibration_dir) / "design_runs.csv")
    d = d[d[list(OUTPUTS)].notna().all(axis=1)]
    names = ["restitution", "static_friction", "rolling_friction", "amplitude_m",
             "frequency_hz", "ball_diameter_m"]
    bounds = {k: (float(d[k].min()), float(d[k].max())) for k in names}
    em = GPEmulator(bounds, outputs=OUTPUTS, n_restarts_optimizer=1, random_state=random_state)
    return em.fit(d[names], d[list(OUTPUTS)])


class TwinModel:
    """predict(theta, effects) for diagnose, from the anchor, the GP difference and the signature
    library (see the module docstring).

    Parameters
    ----------
    conditions : DataFrame - condition_id, frequency_hz, ball_diameter_mm (a subset of the
        library's conditions)
    yield_times_min : dict condition_id -> list of times [min] of the yield observables
    library : (summary, meta) from :func:`load_library`, default results/signatures
    emulator : fitted GPEmulator or None (default :func:`base_emulator`)
    base : names of the calibrated DEM base parameters
    """

    def __init__(self, conditions, yield_times_min=None, library=None, emulator=None,
                 base=("restitution", "amplitude_m")):
        summ, meta = library if library is not None else load_library()
        self.theta_ref = dict(meta["theta_ref"])
        self.base_names = tuple(base)
        unknown = set(self.base_names) - set(self.theta_ref)
        if unknown:
            raise ValueError("unknown base parameter(s) %s" % sorted(unknown))
        self.conditions = conditions.reset_index(drop=True)
        cids = list(self.conditions["condition_id"])
        lib_ids = set(summ["condition_id"])
        missing = [c for c in cids if c not in lib_ids]
        if missing:
            raise ValueError("the signature library has no runs at condition(s) %s" % missing)
        a = summ[summ["label"] == "none"].set_index("condition_id").loc[cids]
        self.anchor = a[["v_mean_m_s", "f_col_hz"]].to_numpy(float)       # (n_cond, 2)
        # standard errors as for a 2-seed mean (the signatures' seeds): the anchor's own se is
        # then overstated by sqrt(2), a signature's difference noise by 15 % - both conservative
        self.n_rep = float(summ["n"].min())
        # the twin's scatter of one run, per condition: heteroscedastic (0.1-0.3 % for the
        # 20.6 mm ball, 0.6-1.3 % for the 17.5 mm one), so pooled over every library label (each
        # label's seeds scatter alike; 2 seeds x 7 labels) rather than over the conditions;
        # floors: 0.25 % of v_mean and 1 /s of f_col (a 0.5 s record counts in steps of 2 /s)
        rel = (summ["v_sd_m_s"] / summ["v_mean_m_s"]) ** 2
        # ... and never below the anchor's own scatter there (f_col has heavy tails: one anchor
        # seed with a chatter episode counts 74 /s where the others count 60)
        own_v = np.nan_to_num((a["v_sd_m_s"] / a["v_mean_m_s"]).to_numpy(float))
        own_f = np.nan_to_num(a["f_col_sd_hz"].to_numpy(float))
        self.v_rel_sd_cond = np.fmax.reduce([np.sqrt(rel.groupby(summ["condition_id"]).mean()
                                                     .loc[cids].to_numpy(float)), own_v,
                                             np.full(len(cids), V_REL_SD_FLOOR)])
        self.v_rel_sd = float(np.sqrt(np.mean(self.v_rel_sd_cond ** 2)))
        f_var = (summ["f_col_sd_hz"] ** 2).groupby(summ["condition_id"]).mean()
        self.f_col_sd_hz = np.fmax.reduce([np.sqrt(f_var.loc[cids].to_numpy(float)), own_f,
                                           np.full(len(cids), F_COL_SD_FLOOR_HZ)])
        self.sig = {}
        for c in CANDIDATES:
            if c.kind != "dem":
                continue
            d = summ[summ["label"] == c.name]
            if not len(d):
                raise ValueError("the signature library has no runs of %s" % c.name)
            d = d.set_index("condition_id").loc[cids]
            self.sig[c.name] = (float(d["strength"].iloc[0]),
                                d[["v_mean_m_s", "f_col_hz"]].to_numpy(float) - self.anchor)
        self.em = emulator if emulator is not None else base_emulator()
        X = self._em_inputs(self.theta_ref)
        self.em_ref = self.em.predict(X)
        self.mass_kg = (STEEL_DENSITY_KG_M3 * math.pi / 6.0
                        * (self.conditions["ball_diameter_mm"].to_numpy(float) * 1e-3) ** 3)
        self.yield_times_min = {k: list(v) for k, v in (yield_times_min or {}).items()}
        keys = []
        for cid in cids:
            keys += [(cid, "v_mean_m_s"), (cid, "f_col_hz")]
            keys += [(cid, "yield_pct@%gmin" % t) for t in self.yield_times_min.get(cid, [])]
        self.keys = pd.MultiIndex.from_tuples(keys, names=["condition_id", "observable"])
        self._kin = candidates("kinetics")

    def _em_inputs(self, theta):
        c = self.conditions
        X = pd.DataFrame({k: np.full(len(c), float(theta.get(k, self.theta_ref[k])))
                          for k in ("restitution", "static_friction", "rolling_friction",
                                    "amplitude_m")})
        X["frequency_hz"] = c["frequency_hz"].to_numpy(float)
        X["ball_diameter_m"] = c["ball_diameter_mm"].to_numpy(float) * 1e-3
        return X

    def twin_scatter(self):
        """{'twin_v_rel_sd': {cid: ..}, 'twin_f_col_sd_hz': {cid: ..}}: one run's scatter per
        condition, for :func:`analysis.hidden.make_hidden_dataset`."""
        cids = list(self.conditions["condition_id"])
        return {"twin_v_rel_sd": dict(zip(cids, map(float, self.v_rel_sd_cond))),
                "twin_f_col_sd_hz": dict(zip(cids, map(float, self.f_col_sd_hz)))}

    @property
    def has_yields(self):
        return any(self.yield_times_min.values())

    def base_params(self):
        """diagnose BaseParameters: the DEM base (starting at theta_ref, bounds of the
        calibration's prior) and, with yields, the powder line's slope and intercept."""
        from analysis.diagnose import BaseParameter
        from analysis import kinetics
        bounds = {"restitution": (0.1, 0.7), "static_friction": (0.3, 0.7),
                  "rolling_friction": (0.1, 0.5), "amplitude_m": (0.010, 0.016)}
        out = [BaseParameter(k, self.theta_ref[k], *bounds[k]) for k in self.base_names]
        if self.has_yields:
            out += [BaseParameter("slope_pct_per_kj", kinetics.PAPER_SLOPE_PCT_PER_KJ, 1.0, 30.0),
                    BaseParameter("intercept_pct", kinetics.PAPER_INTERCEPT_PCT, -20.0, 20.0)]
        return out

    def effects(self):
        """diagnose Effects, strength coordinate in [0, s_max], null 0; kinetics candidates only
        when the observations hold yields."""
        from analysis.diagnose import Effect
        out = []
        for c in CANDIDATES:
            if c.kind == "kinetics" and not self.has_yields:
                continue
            out.append(Effect(c.name, 0.0, c.s_max, null=0.0, kind=c.kind,
                              description="strength = %s" % c.strength_label))
        return out

    def dem_outputs(self, theta, effects=None):
        """(n_cond, 2) array of v_mean, f_col at ``theta`` with DEM effects at their strengths."""
        effects = effects or {}
        y = self.anchor + (self.em.predict(self._em_inputs(theta)) - self.em_ref)
        for name, s in effects.items():
            if name in self.sig and s:
                s_sig, delta = self.sig[name]
                y = y + (float(s) / s_sig) * delta
        return y

    def predict(self, theta, effects=None):
        """Series indexed by (condition_id, observable): v_mean_m_s, f_col_hz and the yields."""
        effects = dict(effects or {})
        unknown = [k for k in effects if k not in self.sig and k not in self._kin]
        if unknown:
            raise ValueError("unknown effect(s) %s" % unknown)
        y = self.dem_outputs(theta, effects)
        out = []
        kin_on = [k for k, s in effects.items() if k in self._kin and s]
        if len(kin_on) > 1:
            raise ValueError("kinetics effects do not compose: %s" % kin_on)
        eff_obj = None
        if kin_on:
            from effects import load_effects
            c = self._kin[kin_on[0]]
            eff_obj = load_effects(c.spec(effects[kin_on[0]]), side="kinetics")[0]
        slope = float(theta.get("slope_pct_per_kj", 0.0))
        intercept = float(theta.get("intercept_pct", 0.0))
        for i, cid in enumerate(self.conditions["condition_id"]):
            v, f = y[i]
            out += [v, f]
            times = self.yield_times_min.get(cid, [])
            if times:
                e_kin = 0.5 * self.mass_kg[i] * v * v
                t_s = np.asarray(times, float) * 60.0
                if eff_obj is None:
                    x = slope * e_kin * f * t_s / 1000.0 + intercept
                else:
                    x = eff_obj.yield_pct(e_kin, f, t_s, slope, intercept)
                out += list(np.asarray(x, float))
        return pd.Series(out, index=self.keys)

    def model_se(self, theta=None):
        """The anchor's standard error per key (pooled relative sd of v_mean, per-condition sd of
        f_col floored by the pooled one, both propagated to the yields through
        E_tot = m v^2 f_col t / 2)."""
        theta = dict(theta or self.theta_ref)
        theta.setdefault("slope_pct_per_kj", 9.49)
        y = self.dem_outputs(theta)
        out = []
        for i, cid in enumerate(self.conditions["condition_id"]):
            v, f = y[i]
            v_se = self.v_rel_sd_cond[i] * v / math.sqrt(self.n_rep)
            f_se = self.f_col_sd_hz[i] / math.sqrt(self.n_rep)
            out += [v_se, f_se]
            m = self.mass_kg[i]
            for t in self.yield_times_min.get(cid, []):
                out.append(abs(theta["slope_pct_per_kj"]) * t * 60.0 / 1000.0
                           * math.hypot(m * v * f * v_se, 0.5 * m * v * v * f_se))
        return pd.Series(out, index=self.keys)


def yield_times_of(dataset):
    """condition_id -> yield times [min] of a Dataset (empty without yields)."""
    if dataset.yields is None:
        return {}
    return {cid: list(g["time_min"].astype(float))
            for cid, g in dataset.yields.groupby("condition_id", sort=False)}


def factory(dataset, library=None, emulator=None, base=("restitution", "amplitude_m")):
    """diagnose --model hook: the twin model for ``dataset``'s conditions and yield times."""
    m = TwinModel(dataset.conditions, yield_times_of(dataset), library=library,
                  emulator=emulator, base=base)
    return {"predict": m.predict, "base_params": m.base_params(), "effects": m.effects(),
            "model_se": m.model_se(), "crn_correlation": 0.0,
            "noise_observables": {"v_mean_m_s", "f_col_hz"}, "model": m}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--build", action="store_true", help="run and write the signature library")
    ap.add_argument("--replicates", type=int, default=2)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=str(SIGNATURE_DIR))
    a = ap.parse_args(argv)
    if not a.build:
        summ, meta = load_library(a.out)
        print(summ.to_string())
        return 0
    try:
        summ = build_library(a.out, replicates=a.replicates, workers=a.workers)
    except (RuntimeError, FileNotFoundError, ValueError) as exc:
        print("analysis.twin_model: error: %s" % exc, file=sys.stderr)
        return 2
    piv = summ.pivot(index="condition_id", columns="label", values="dv_pct")
    print(piv.round(2).to_string())
    return 0


if __name__ == "__main__":
    sys.exit(main())
