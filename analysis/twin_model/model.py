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
  signature strengths (half and all of its diagnose range, ``SIGNATURE_LEVELS``), same seeds as
  the anchor; the change of each observable is interpolated piecewise linearly through 0 and
  the levels in the effect's strength coordinate (chosen per effect so that the response is
  close to linear: the restitution drop k, the arm curvature, (f_0/f_n)^2 for the mount's
  stiffness, h^2 for the powder layer's absorbed energy, the extra rolling friction, the drag
  multiplier; one level was not enough: jar compliance's resonance gain and the impact
  observables bend). Effects add. Jar compliance makes the flight bistable (the ball meets the
  wall at ~4 or ~1 m/s, depending on strength and start): each library run is classed by its
  impact pattern and a condition whose measured track is in the 'late' pattern takes only the
  late runs (:func:`impact_patterns`, :func:`effect_levels`), so two motions are never averaged;
* **impact observables** (when the dataset has tracks with the jar, :mod:`analysis.flights`:
  apparent restitution, approach speed, impact phase, jar amplitude, vertical rms speed per
  condition): anchor and signatures read from the library's recordings by the same operator,
  base parameters through a GP on the calibration's design runs (:func:`flight_emulator`, also
  as a difference). They pin restitution (e_app) and stroke (jar amplitude) directly, so the
  recalibration can no longer hide an effect's footprint on v_mean in them;
* **kinetics**: yields from the predicted E_kin = m v^2 / 2 and f_col through the powder line
  X = a E_tot + b (a, b base parameters) or a kinetics effect's ``modify_kinetics``; exact.

The model's own noise (``model_se``) is the anchor's replicate standard error (pooled relative
sd over the conditions); the signatures carry the same noise on both sides of the difference, so
diagnose is told ``crn_correlation = 0`` and its identifiability gate subtracts that noise from
every footprint: an effect the twin cannot tell from its chaos (air drag, the decoy) is never
identifiable.

The catalog is :mod:`analysis.catalog`, the library
:mod:`analysis.twin_model.library`; this module is the model assembled from them.

    python -m analysis.diagnose --dataset DIR --model analysis.twin_model:factory --out DIR
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

#: calibration prior bounds of the DEM base parameters (declared in analysis.calibrate)
from analysis.parameter_space import CALIBRATED as BASE_BOUNDS
from analysis.catalog import CANDIDATES, candidates
from analysis.twin_model.library import (CALIBRATION_DIR, DESIGN_FLIGHTS_FILE, SIGNATURE_DIR,
                                         in_late_pattern, library_at, load_library)

OUTPUTS = ("v_mean_m_s", "f_col_hz")
#: the base parameters the emulators take (with frequency and ball diameter)
EM_PARAMS = ("restitution", "static_friction", "rolling_friction", "amplitude_m")
STEEL_DENSITY_KG_M3 = 7800.0  # analysis.kinetics.STEEL_DENSITY_KG_M3 (checked in the tests)
V_REL_SD_FLOOR = 0.0025       # smallest replicate sd of one run's v_mean (relative)
F_COL_SD_FLOOR_HZ = 1.0       # smallest replicate sd of one run's f_col [1/s]
#: smallest replicate sd of one run's impact observables (analysis.flights): absolute
FLIGHT_SD_FLOORS = {"e_app": 0.003, "v_in_m_s": 0.005, "impact_phase_rad": 0.01,
                    "jar_amplitude_m": 0.0, "vy_rms_m_s": 0.0005}


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


def flight_emulator(lib_dir=SIGNATURE_DIR, random_state=0):
    """GP emulator of the impact observables on the calibration's design runs (their recordings
    read by analysis.flights; design_flights.csv of the library), runs in end-to-end flight."""
    from analysis.emulator import GPEmulator
    from analysis.flights import FLIGHT_OBSERVABLES
    p = Path(lib_dir) / DESIGN_FLIGHTS_FILE
    if not p.exists():
        raise FileNotFoundError("%s missing: run `python -m analysis.twin_model --flights`" % p)
    d = pd.read_csv(p)
    d = d[d[list(FLIGHT_OBSERVABLES)].notna().all(axis=1)]
    if "motion_mode" in d.columns:
        d = d[d["motion_mode"] == "end_to_end"]
    names = ["restitution", "static_friction", "rolling_friction", "amplitude_m",
             "frequency_hz", "ball_diameter_m"]
    bounds = {k: (float(d[k].min()), float(d[k].max())) for k in names}
    em = GPEmulator(bounds, outputs=FLIGHT_OBSERVABLES, n_restarts_optimizer=1,
                    random_state=random_state)
    return em.fit(d[names], d[list(FLIGHT_OBSERVABLES)])


def effect_levels(d, cids, cols, anchor, patterns=None):
    """One effect's signature per condition: a list over ``cids`` of (strengths (k,), changes
    (k, n_cols) from the anchor), strengths ascending.

    With the per-pattern columns of :func:`summarise_library` (``<col>@normal``,
    ``<col>@late``), each condition takes only the library runs in its own impact pattern
    (``patterns[cid]``, default 'normal'): a level whose runs are all in the other pattern is
    left out, so two steady motions are never averaged. The normal branch starts at (0, 0); a
    late branch (the anchor has none) holds its levels only, extended flat below the first and
    linearly above the last. Without such columns: all runs, one branch from (0, 0).
    """
    patterns = patterns or {}
    levels = sorted(float(x) for x in d["strength"].unique())
    by = {lv: d[d["strength"] == lv].set_index("condition_id") for lv in levels}
    split = all(c + "@normal" in d.columns for c in cols)
    out = []
    for i, cid in enumerate(cids):
        pat = patterns.get(cid, "normal") if split else "normal"
        xs, ds = ([0.0], [np.zeros(len(cols))]) if pat == "normal" else ([], [])
        for lv in levels:
            row = by[lv].loc[cid]
            v = (row[[c + "@" + pat for c in cols]] if split else row[cols]).to_numpy(float)
            if split and not np.all(np.isfinite(v[:1])):
                continue                      # no run of this level in this pattern
            xs.append(lv)
            ds.append(np.nan_to_num(v - anchor[i]))
        if not xs:                            # the effect never reaches this pattern here
            xs, ds = [0.0], [np.zeros(len(cols))]
        out.append((np.array(xs), np.array(ds)))
    return out


def interp_levels(sig, s):
    """(n_cond, n_cols) change at strength ``s``: per condition piecewise linear through its
    levels, the last segment extended beyond the top, flat below a late branch's first level."""
    rows = []
    for xs, ds in sig:
        if len(xs) == 1 or s <= xs[0]:
            rows.append(ds[0] if len(xs) == 1 or xs[0] > 0 else
                        ds[0] + (s - xs[0]) / (xs[1] - xs[0]) * (ds[1] - ds[0]))
            continue
        k = int(np.clip(np.searchsorted(xs, s) - 1, 0, len(xs) - 2))
        w = (s - xs[k]) / (xs[k + 1] - xs[k])
        rows.append((1.0 - w) * ds[k] + w * ds[k + 1])
    return np.array(rows)


def curvatures(xs, ds):
    """(k - 1, n_cols) curvature scale of each segment of one condition's signature: at every
    interior level the deviation from the line through its neighbours over the product of its
    two spacings (|f''| / 2 for a quadratic), a segment taking the larger of its two ends; zero
    with fewer than three points."""
    k = len(xs)
    if k < 2:
        return np.zeros((0, ds.shape[1]))
    c = np.zeros((k, ds.shape[1]))
    for j in range(1, k - 1):
        a, b = xs[j] - xs[j - 1], xs[j + 1] - xs[j]
        line = ds[j - 1] + (ds[j + 1] - ds[j - 1]) * a / (a + b)
        c[j] = np.abs(ds[j] - line) / (a * b)
    return np.maximum(c[:-1], c[1:])


def interp_sd(sig, curv, s, rough=None):
    """(n_cond, n_cols) standard error of :func:`interp_levels` at strength ``s``: zero at a
    level, C (s - x_k) (x_k+1 - s) inside a segment (exact for a quadratic response, a scale
    for a rougher one), C (s - x_k-1)(s - x_k) beyond the top; below a late branch's first level
    (held flat) the first segment's slope times the distance is added. Where ``rough[i]`` (a
    late impact pattern, whose flight passes through changes of motion between levels) a
    segment may hold a step anywhere: at least |d_k+1 - d_k| sqrt(w (1 - w)), the rms error of
    linear interpolation across a step at a uniformly unknown place."""
    rows = []
    for i, ((xs, ds), C) in enumerate(zip(sig, curv)):
        z = np.zeros(ds.shape[1])
        if len(xs) < 2 or (s <= xs[0] and xs[0] <= 0):
            rows.append(z)
        elif s <= xs[0]:
            slope = np.abs(ds[1] - ds[0]) / (xs[1] - xs[0])
            rows.append(slope * (xs[0] - s) + C[0] * (xs[0] - s) * (xs[1] - s))
        elif s >= xs[-1]:
            rows.append(C[-1] * (s - xs[-1]) * (s - xs[-2]))
        else:
            k = int(np.clip(np.searchsorted(xs, s) - 1, 0, len(xs) - 2))
            sd = C[k] * (s - xs[k]) * (xs[k + 1] - s)
            if rough is not None and rough[i]:
                w = (s - xs[k]) / (xs[k + 1] - xs[k])
                sd = np.maximum(sd, np.abs(ds[k + 1] - ds[k]) * math.sqrt(w * (1.0 - w)))
            rows.append(sd)
    return np.array(rows)


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
    flight_conditions : condition ids whose impact observables (analysis.flights: e_app,
        v_in_m_s, impact_phase_rad, jar_amplitude_m, vy_rms_m_s) are predicted too - the
        conditions with a jar track. Their anchor and signatures come from the library's runs
        read by the same operator, the base parameters act through :func:`flight_emulator`
        (again as a difference), and their model noise is one run's scatter per condition,
        pooled over the library's labels: the anchor mean's se in ``model_se``, and one run's
        sd added to the measured sd by :func:`factory` (a track is one realisation of the
        chaotic motion: its own within-record se does not see the run-to-run part).
    flight_emulator : fitted GPEmulator of the impact observables or None (default
        :func:`flight_emulator`)
    patterns : dict condition_id -> 'normal' or 'late', the impact pattern the measured ball is
        in (from its jar track, :func:`impact_patterns`); the signatures there use only library
        runs in that pattern (jar compliance makes the flight bistable). Default: 'normal'.
    """

    def __init__(self, conditions, yield_times_min=None, library=None, emulator=None,
                 base=("restitution", "amplitude_m"), flight_conditions=(),
                 flight_emulator=None, patterns=None):
        summ, meta = library if library is not None else load_library()
        self.patterns = dict(patterns or {})
        self.theta_ref = dict(meta["theta_ref"])
        self.base_names = tuple(base)
        unknown = set(self.base_names) - set(self.theta_ref)
        if unknown:
            raise ValueError("unknown base parameter(s) %s" % sorted(unknown))
        self.conditions = conditions.reset_index(drop=True)
        cids = list(self.conditions["condition_id"])
        summ = library_at(self.conditions, (summ, meta))
        a = summ[summ["label"] == "none"].set_index("condition_id").loc[cids]
        self.anchor = a[["v_mean_m_s", "f_col_hz"]].to_numpy(float)       # (n_cond, 2)
        # standard errors as for a 2-seed mean (the signatures' seeds): the anchor's own se is
        # then overstated by sqrt(2), a signature's difference noise by 15 % - both conservative
        self.n_rep = float(summ["n"].min())
        # the twin's scatter of one run, per condition: heteroscedastic (0.1-0.3 % for the
        # 20.6 mm ball, 0.6-1.3 % for the 17.5 mm one), so pooled over every library label (each
        # label's seeds scatter alike; 2 seeds x 7 labels) rather than over the conditions;
        # floors: 0.25 % of v_mean and 1 /s of f_col (a 0.5 s record counts in steps of 2 /s)
        # a level whose seeds split between the two impact patterns scatters by the jump
        # between two motions, not by one motion's chaos: left out of the pooling
        pure = summ
        if "n_late_pattern" in summ.columns:
            nl = summ["n_late_pattern"]
            pure = summ[(nl == 0) | (nl == summ["n"])]
        rel = (pure["v_sd_m_s"] / pure["v_mean_m_s"]) ** 2
        # ... and never below the anchor's own scatter there (f_col has heavy tails: one anchor
        # seed with a chatter episode counts 74 /s where the others count 60)
        own_v = np.nan_to_num((a["v_sd_m_s"] / a["v_mean_m_s"]).to_numpy(float))
        own_f = np.nan_to_num(a["f_col_sd_hz"].to_numpy(float))
        self.v_rel_sd_cond = np.fmax.reduce([np.sqrt(rel.groupby(pure["condition_id"]).mean()
                                                     .loc[cids].to_numpy(float)), own_v,
                                             np.full(len(cids), V_REL_SD_FLOOR)])
        self.v_rel_sd = float(np.sqrt(np.mean(self.v_rel_sd_cond ** 2)))
        f_var = (pure["f_col_sd_hz"] ** 2).groupby(pure["condition_id"]).mean()
        self.f_col_sd_hz = np.fmax.reduce([np.sqrt(f_var.loc[cids].to_numpy(float)), own_f,
                                           np.full(len(cids), F_COL_SD_FLOOR_HZ)])
        self.sig = {}
        for c in CANDIDATES:
            if c.kind != "dem":
                continue
            d = summ[summ["label"] == c.name]
            if not len(d):
                raise ValueError("the signature library has no runs of %s" % c.name)
            self.sig[c.name] = effect_levels(d, cids, ["v_mean_m_s", "f_col_hz"], self.anchor,
                                       self.patterns)
        self.sig_curv = {k: [curvatures(xs, ds) for xs, ds in v] for k, v in self.sig.items()}
        self._gp_cache = {}
        self.em = emulator if emulator is not None else base_emulator()
        X = self._em_inputs(self.theta_ref)
        self.em_ref = self.em.predict(X)
        self._init_flights(summ, a, cids, flight_conditions, flight_emulator, pure)
        self.yield_times_min = {k: list(v) for k, v in (yield_times_min or {}).items()}
        self._init_keys()

    def _init_keys(self):
        """Ball masses, the prediction's keys (condition_id, observable) and the kinetics
        candidates, from the conditions, yield times and flight conditions."""
        self.mass_kg = (STEEL_DENSITY_KG_M3 * math.pi / 6.0
                        * (self.conditions["ball_diameter_mm"].to_numpy(float) * 1e-3) ** 3)
        keys = []
        for cid in self.conditions["condition_id"]:
            keys += [(cid, "v_mean_m_s"), (cid, "f_col_hz")]
            keys += [(cid, "yield_pct@%gmin" % t) for t in self.yield_times_min.get(cid, [])]
            if cid in self.flight_conditions:
                keys += [(cid, k) for k in self.flight_obs]
        self.keys = pd.MultiIndex.from_tuples(keys, names=["condition_id", "observable"])
        self._kin = candidates("kinetics")

    def _init_flights(self, summ, a, cids, flight_conditions, emulator, pure=None):
        from analysis.flights import FLIGHT_OBSERVABLES
        self.flight_obs = tuple(FLIGHT_OBSERVABLES)
        self.flight_conditions = [c for c in cids if c in set(flight_conditions or ())]
        unknown = set(flight_conditions or ()) - set(cids)
        if unknown:
            raise ValueError("flight conditions %s are not among the conditions"
                             % sorted(unknown))
        if not self.flight_conditions:
            return
        missing = [k for k in self.flight_obs if k not in summ.columns]
        if missing:
            raise ValueError("the signature library has no impact observables (%s): run "
                             "`python -m analysis.twin_model --flights`" % ", ".join(missing))
        fo = list(self.flight_obs)
        self.fl_anchor = a[fo].to_numpy(float)
        if not np.all(np.isfinite(self.fl_anchor)):
            raise ValueError("the library's anchor has no impact observables at some condition")
        pure = summ if pure is None else pure            # single-pattern levels only
        sd = pure[[k + "_sd" for k in fo]].pow(2).groupby(pure["condition_id"]).mean() \
            .loc[cids].to_numpy(float) ** 0.5
        floors = np.array([FLIGHT_SD_FLOORS[k] for k in fo])
        self.fl_sd_cond = np.fmax(np.nan_to_num(sd), floors)
        self.fl_sig = {}
        for c in CANDIDATES:
            if c.kind != "dem":
                continue
            self.fl_sig[c.name] = effect_levels(summ[summ["label"] == c.name], cids, fo,
                                          self.fl_anchor, self.patterns)
        self.fl_curv = {k: [curvatures(xs, ds) for xs, ds in v]
                        for k, v in self.fl_sig.items()}
        self.fl_em = emulator if emulator is not None else flight_emulator()
        self.fl_em_ref = self.fl_em.predict(self._em_inputs(self.theta_ref))

    def flight_outputs(self, theta, effects=None):
        """(n_cond, 5) impact observables at ``theta`` with DEM effects at their strengths."""
        return self._assemble(self.fl_anchor, self.fl_em, self.fl_em_ref, self.fl_sig, theta,
                              effects)

    def _assemble(self, anchor, em, em_ref, sigs, theta, effects):
        """anchor + GP(theta) - GP(theta_ref) + the interpolated signatures of the effects."""
        y = anchor + (self._gp(em, theta) - em_ref)
        for name, s in (effects or {}).items():
            if name in sigs and s:
                y = y + interp_levels(sigs[name], float(s))
        return y

    def _gp(self, em, theta):
        """em's prediction at ``theta``, cached (a strength scan or a finite difference in a
        strength calls predict many times at the same base parameters)."""
        key = (id(em), tuple(float(theta.get(k, self.theta_ref[k])) for k in EM_PARAMS))
        if key not in self._gp_cache:
            if len(self._gp_cache) > 512:
                self._gp_cache.clear()
            self._gp_cache[key] = em.predict(self._em_inputs(theta))
        return self._gp_cache[key]

    def _em_inputs(self, theta):
        c = self.conditions
        X = pd.DataFrame({k: np.full(len(c), float(theta.get(k, self.theta_ref[k])))
                          for k in EM_PARAMS})
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
        out = [BaseParameter(k, self.theta_ref[k], *BASE_BOUNDS[k]) for k in self.base_names]
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
        return self._assemble(self.anchor, self.em, self.em_ref, self.sig, theta, effects)

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
        fl = self.flight_outputs(theta, effects) if self.flight_conditions else None
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
            if cid in self.flight_conditions:
                out += list(fl[i])
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
            if cid in self.flight_conditions:
                out += list(self.fl_sd_cond[i] / math.sqrt(self.n_rep))
        return pd.Series(out, index=self.keys)

    def resolution_se(self, effects):
        """The library's interpolation error per key with DEM ``effects`` {name: strength} on
        (:func:`interp_sd` of each signature, summed in quadrature over the effects and
        propagated to the yields like :meth:`model_se`): zero at the library's levels, largest
        between levels whose response bends; in a condition measured in the late impact pattern
        (jar compliance's second flight, whose impact observables jump between the library's
        levels) at least the rms error across a step. diagnose's ``effect_se``."""
        n = len(self.conditions)
        dem = [(k, float(v)) for k, v in (effects or {}).items() if k in self.sig and v]
        var = np.zeros((n, 2))
        fvar = np.zeros((n, len(self.flight_obs))) if self.flight_conditions else None
        rough = [self.patterns.get(c) == "late" for c in self.conditions["condition_id"]]
        for name, st in dem:
            var += interp_sd(self.sig[name], self.sig_curv[name], st, rough) ** 2
            if fvar is not None:
                fvar += interp_sd(self.fl_sig[name], self.fl_curv[name], st, rough) ** 2
        sd = np.sqrt(var)
        y = self.anchor                 # v, f_col at which the yields' se is propagated
        from analysis.kinetics import PAPER_SLOPE_PCT_PER_KJ as slope
        out = []
        for i, cid in enumerate(self.conditions["condition_id"]):
            v, f = y[i]
            out += [sd[i, 0], sd[i, 1]]
            m = self.mass_kg[i]
            for t in self.yield_times_min.get(cid, []):
                out.append(abs(slope) * t * 60.0 / 1000.0
                           * math.hypot(m * v * f * sd[i, 0], 0.5 * m * v * v * sd[i, 1]))
            if cid in self.flight_conditions:
                out += list(np.sqrt(fvar[i]))
        return pd.Series(out, index=self.keys)

    def flight_run_sd(self):
        """One twin run's scatter of the impact observables per (condition, observable): the
        part of a measured track's deviation that its within-record se does not see (a track is
        one realisation of the chaotic motion). :func:`factory` adds it to the measured sd."""
        rows, vals = [], []
        for i, cid in enumerate(self.conditions["condition_id"]):
            if cid in self.flight_conditions:
                rows += [(cid, k) for k in self.flight_obs]
                vals += list(self.fl_sd_cond[i])
        return pd.Series(vals, index=pd.MultiIndex.from_tuples(
            rows, names=["condition_id", "observable"]), dtype=float)


def yield_times_of(dataset):
    """condition_id -> yield times [min] of a Dataset (empty without yields)."""
    if dataset.yields is None:
        return {}
    return {cid: list(g["time_min"].astype(float))
            for cid, g in dataset.yields.groupby("condition_id", sort=False)}


def impact_patterns(flights, library=None, conditions=None):
    """condition_id -> 'late' or 'normal': the impact pattern of each measured track (its
    approach speed against LATE_V_IN_FRAC x the library anchor's there). With ``conditions``
    (the dataset's) the library is matched to them by physics; without, by condition id."""
    library = library if library is not None else load_library()
    fl_ids = list(dict.fromkeys(flights["condition_id"]))
    if conditions is None:
        summ = library[0]
    else:
        summ = library_at(conditions[conditions["condition_id"].isin(fl_ids)], library)
    a = summ[summ["label"] == "none"].set_index("condition_id")
    if "v_in_m_s" not in a.columns:
        return {}
    v = flights[flights["observable"] == "v_in_m_s"].set_index("condition_id")["value"]
    return {cid: ("late" if in_late_pattern(x, a.loc[cid, "v_in_m_s"]) else "normal")
            for cid, x in v.items() if cid in a.index}


def dataset_observations(dataset, flights=True):
    """(observations, flight condition ids, flight observations) of ``dataset``: its summary
    and yields, and with ``flights`` the impact observables of its tracks that carry the jar
    (:func:`analysis.flights.dataset_flights`)."""
    from analysis.diagnose import observations_from_dataset
    from analysis.flights import dataset_flights
    obs = observations_from_dataset(dataset)
    fl, fl_ids = None, []
    if flights and dataset.tracks:
        fl = dataset_flights(dataset)
        if len(fl):
            obs = pd.concat([obs, fl], ignore_index=True)
            fl_ids = list(dict.fromkeys(fl["condition_id"]))
    return obs, fl_ids, fl


def with_run_sd(obs, run_sd):
    """``obs`` whose sd is at least one twin run's scatter (``run_sd``, a Series by
    (condition_id, observable)) where it names one: a track is one realisation of a chaotic
    motion. The operator's standard error over the record and the scatter of one run's record
    mean both measure that realisation's chaos - the larger is kept (adding them in quadrature
    counted it twice: on 11 no-effect datasets the impact observables' mean z^2 was 0.23-0.45
    for e_app and the impact phase)."""
    key = list(zip(obs["condition_id"], obs["observable"]))
    add = np.array([run_sd.get(k, 0.0) for k in key])
    out = obs.copy()
    out["sd"] = np.fmax(out["sd"].to_numpy(float), add)
    return out


def factory(dataset, library=None, emulator=None, base=("restitution", "amplitude_m"),
            flights=True, flight_emulator=None):
    """diagnose --model hook: the twin model for ``dataset``'s conditions and yield times, and
    the observations it predicts (``observations``): the dataset's summary and yields, and with
    ``flights`` the impact observables of its tracks that carry the jar (analysis.flights), their
    sd the operator's within-record se combined with one twin run's scatter there."""
    from analysis.flights import FLIGHT_OBSERVABLES
    obs, fl_ids, fl = dataset_observations(dataset, flights)
    patterns = impact_patterns(fl, library, dataset.conditions) if fl_ids else {}
    m = TwinModel(dataset.conditions, yield_times_of(dataset), library=library,
                  emulator=emulator, base=base, flight_conditions=fl_ids,
                  flight_emulator=flight_emulator, patterns=patterns)
    if fl_ids:
        obs = with_run_sd(obs, m.flight_run_sd())
    noise = {"v_mean_m_s", "f_col_hz"} | (set(FLIGHT_OBSERVABLES) if fl_ids else set())
    from analysis.diagnose import ModelSpec
    return ModelSpec(predict=m.predict, base_params=m.base_params(), effects=m.effects(),
                     model_se=m.model_se(), effect_se=m.resolution_se, crn_correlation=0.0,
                     observations=obs, noise_observables=noise, model=m, patterns=patterns)
