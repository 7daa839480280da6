"""The one model of the twin at a dataset's conditions: emulators fitted to every twin run made
for it, built in waves of one design.

:class:`EmulatedTwin` holds one GP emulator (:class:`analysis.emulator.GPEmulator`) per
motion mode (end-to-end flights, chatter: :meth:`EmulatedTwin.mode_labels`) and observable the
loop compares, and a classifier of the mode (:class:`analysis.emulator.ModeClassifier`); it
predicts their mixture (:func:`analysis.emulator.mix_modes`). The observables: the speed in the dataset's frame, f_col and, where the dataset's
tracks carry the jar, the impact observables of :mod:`analysis.flights` - over the base
parameters, every candidate effect's strength JOINTLY (an effect's response at another
restitution is learned, not assumed equal to one anchor's) and the conditions' frequency and
ball. It is fitted to every twin run made for the dataset: design points, replicates and the
confirmation runs at a fitted point. The yields follow from the speed and the rate through the
powder line (or a kinetics effect) exactly, as in the paper.

It meets :class:`TwinModelContract`, the shape the loop's calibration and diagnosis use
(``predict(theta, effects)`` a Series by (condition_id, observable); ``model_se`` the
emulator's own sd of the twin's mean there; ``flight_run_sd`` one run's chaos of the impact observables, which a measured
track - one realisation - carries).

:func:`build_in_waves` makes the runs: wave 0 a space-filling design with one effect on in half
its points, the reference point with replicates (the twin's chaos per condition); then waves
whose points go where the data's plausible region lies (:func:`analysis.history_matching.
next_wave`), with no effect and with each candidate effect free in turn.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Protocol, runtime_checkable

import numpy as np
import pandas as pd

from analysis.emulator import (GPEmulator, ModeClassifier, ModeComponents, Prediction,
                               mix_modes)
from analysis.history_matching import (DesignSpace, design_runs, effect_input,
                                       initial_design, next_wave)

#: observables emulated in log space (relative changes that multiply)
LOG_OBSERVABLES = ("vy_rms_m_s",)
#: the conditions' inputs of every emulator
CONDITION_INPUTS = ("frequency_hz", "ball_diameter_m")
#: the speed column of a run in each velocity frame
SPEED_COLUMN = {"lab": "v_mean_m_s", "jar": "v_mean_jar_m_s"}
#: steel density for the ball mass in E_kin [kg/m^3]
STEEL_DENSITY_KG_M3 = 7800.0


@runtime_checkable
class TwinModelContract(Protocol):
    """What the loop's calibration and diagnosis need of a model of the twin. ``theta`` and
    ``effects`` are mappings name -> value: the loop passes
    :class:`analysis.parameter_space.ParameterVector` (names, units and bounds), a test may
    pass a plain dict."""

    theta_ref: dict
    flight_conditions: list

    def base_params(self) -> list: ...

    def effects(self) -> list: ...

    def predict(self, theta: Mapping, effects: Mapping | None = None) -> pd.Series: ...

    def model_se(self, theta: Mapping | None = None) -> pd.Series: ...

    def flight_run_sd(self) -> pd.Series: ...


class EmulatedTwin:
    """Emulators of the twin at a dataset's conditions.

    Parameters
    ----------
    conditions : DataFrame - condition_id, frequency_hz, ball_diameter_mm [, amplitude_mm]
    space : DesignSpace - base parameters and candidate effects
    velocity_frame : 'lab' or 'jar' - the frame of the measured speed
    flight_conditions : condition ids whose observations hold the impact observables
    yield_times_min : {condition_id: [t, ...]} - yield times of the dataset
    theta_ref : dict - the reference base parameters (the design's centre; the loop's start)
    seed : int - the hyperparameter optimiser's seed
    observation : names of the observation effects diagnosed (catalog kind 'observation':
        the measurement chain; applied to the assembled prediction, never a design input)
    pinned : {effect name: {parameter: value}} - observation effects whose parameters the
        dataset states (videos/video.json: :func:`analysis.measurements.observation_pins`),
        applied to every prediction; a pinned effect is not diagnosed
    fit_cache : :class:`analysis.fit_cache.FitCache` or None - the emulators' and the
        classifier's hyperparameters of earlier fits of the same runs (the same model, faster)

    Attributes (after :meth:`fit`)
    ----------
    emulators_ : {observable: GPEmulator}
    runs_ : DataFrame - the training runs
    keys : MultiIndex (condition_id, observable) of :meth:`predict`
    """

    def __init__(self, conditions, space: DesignSpace, *, velocity_frame="lab",
                 flight_conditions=(), yield_times_min=None, theta_ref=None, seed=0,
                 observation=(), pinned=None, fit_cache=None):
        self.conditions = conditions.reset_index(drop=True)
        self.space = space
        if velocity_frame not in SPEED_COLUMN:
            raise ValueError("velocity_frame must be 'lab' or 'jar', got %r" % velocity_frame)
        self.velocity_frame = velocity_frame
        cids = list(self.conditions["condition_id"])
        self.flight_conditions = [c for c in cids if c in set(flight_conditions or ())]
        self.yield_times_min = {k: list(v) for k, v in (yield_times_min or {}).items()}
        self.theta_ref = dict(theta_ref or {p.name: float(np.mean(p.prior))
                                            for p in space.base})
        self.base_names = tuple(space.base_names)
        self.held = {}
        self.seed = seed
        self.fit_cache = fit_cache
        from analysis.catalog import candidates
        obs_c = candidates("observation")
        bad = [n for n in observation if n not in obs_c]
        if bad:
            raise ValueError("not an observation effect: %s (observation effects: %s)"
                             % (", ".join(bad), ", ".join(obs_c) or "none"))
        self.pinned = {k: dict(v) for k, v in (pinned or {}).items()}
        both = [n for n in observation if n in self.pinned]
        if both:
            raise ValueError("observation effect(s) %s are pinned by the dataset and cannot "
                             "also be diagnosed" % ", ".join(both))
        from effects import load_effects
        self._pinned_objs = load_effects(self.pinned, side="observation")
        if len(self._pinned_objs) != len(self.pinned):
            raise ValueError("pinned effects must be observation effects: %s"
                             % ", ".join(sorted(self.pinned)))
        self.observation = {n: obs_c[n] for n in observation}
        #: the emulator's mean is a smooth function: two predictions share their noise
        #: (diagnose's finite differences carry none)
        self.crn_correlation = 1.0
        #: model_se(theta, effects) is the emulator's sd where a fit asks: the loop's fits carry
        #: it in their likelihood
        self.state_dependent_se = True
        from analysis.flights import FLIGHT_OBSERVABLES
        self.flight_obs = tuple(FLIGHT_OBSERVABLES) if self.flight_conditions else ()
        d_m = self.conditions["ball_diameter_mm"].to_numpy(float) * 1e-3
        self.mass_kg = STEEL_DENSITY_KG_M3 * math.pi / 6.0 * d_m ** 3
        self._X_cond = pd.DataFrame({"frequency_hz": self.conditions["frequency_hz"]
                                     .to_numpy(float), "ball_diameter_m": d_m})
        # the keys of predict, and where each comes from (built together): the row of the
        # stacked (speed, f_col, impact observables) x condition table and its condition, or,
        # for a yield, its condition and time [s]
        rows = {o: j for j, o in enumerate(("v_mean_m_s", "f_col_hz") + self.flight_obs)}
        keys, direct, d_row, d_col, y_pos, y_col, y_t = [], [], [], [], [], [], []
        for i, cid in enumerate(cids):
            after = list(self.flight_obs) if cid in self.flight_conditions else []
            for o in ["v_mean_m_s", "f_col_hz"]:
                direct.append(len(keys)), d_row.append(rows[o]), d_col.append(i)
                keys.append((cid, o))
            for t in self.yield_times_min.get(cid, []):
                y_pos.append(len(keys)), y_col.append(i), y_t.append(float(t) * 60.0)
                keys.append((cid, "yield_pct@%gmin" % t))
            for o in after:
                direct.append(len(keys)), d_row.append(rows[o]), d_col.append(i)
                keys.append((cid, o))
        self.keys = pd.MultiIndex.from_tuples(keys, names=["condition_id", "observable"])
        #: each key's condition (its index in self.conditions)
        self._key_condition = np.array([cids.index(k[0]) for k in keys], int)
        self._lay = (np.array(direct, int), np.array(d_row, int), np.array(d_col, int),
                     np.array(y_pos, int), np.array(y_col, int), np.array(y_t, float))

    # ------------------------------------------------------------------------ fitting
    @property
    def observables(self):
        """Run columns emulated: the frame's speed, f_col, the impact observables."""
        return (SPEED_COLUMN[self.velocity_frame], "f_col_hz") + self.flight_obs

    def bounds(self):
        b = self.space.bounds()
        for c in CONDITION_INPUTS:
            lo, hi = float(self._X_cond[c].min()), float(self._X_cond[c].max())
            pad = max(0.05 * (hi - lo), 0.02 * abs(lo))
            b[c] = (lo - pad, hi + pad)
        return b

    def inputs_of(self, runs: pd.DataFrame) -> pd.DataFrame:
        """Emulator inputs of training runs: the base parameters as run (read from each run's
        config, so a stated stroke is the one run), the effect strengths, the condition. A
        table without configs (a loop's ``model_runs.csv``) gives the design's columns and
        the condition of its ``condition_id`` (a stated stroke applied as the design does)."""
        X = pd.DataFrame({n: runs[n].to_numpy(float) for n in self.space.effect_names})
        if "config" in runs:
            for n in self.space.base_names + list(CONDITION_INPUTS):
                X[n] = [float(c[n]) for c in runs["config"]]
            return X[list(self.bounds())]
        cids = list(self.conditions["condition_id"])
        unknown = sorted(set(runs["condition_id"]) - set(cids))
        if unknown:
            raise ValueError("runs at conditions the model does not hold: %s" % unknown)
        row = runs["condition_id"].map({c: i for i, c in enumerate(cids)}).to_numpy(int)
        for n in CONDITION_INPUTS:
            X[n] = self._X_cond[n].to_numpy(float)[row]
        for n in self.space.base_names:
            X[n] = runs[n].to_numpy(float)
        stated = self.conditions.get("amplitude_mm")
        if stated is not None and "amplitude_m" in X:
            a = stated.to_numpy(float)[row] * 1e-3
            X["amplitude_m"] = np.where(np.isfinite(a), a, X["amplitude_m"])
        return X[list(self.bounds())]

    def fit(self, runs: pd.DataFrame):
        """Fit the motion-mode classifier and one emulator per observable and mode to every
        run where the observable is finite (a run in another motion mode may have no impact
        observables).

        runs : DataFrame with columns config (the run config), the design's effect inputs
            (``effect:<name>``), the observables and ``motion_mode`` (without it: one mode)
        """
        b = self.bounds()
        modes = self.mode_labels(runs)
        keep = np.array([k is not None for k in modes], bool)
        if not keep.any():
            raise ValueError("no run has every emulated observable finite (%s)"
                             % ", ".join(self.observables))
        X, modes, kept = self.inputs_of(runs)[keep], modes[keep], runs[keep]
        self.mode_classifier_ = ModeClassifier(b, random_state=self.seed,
                                               fit_cache=self.fit_cache).fit(X, modes)
        self.emulators_ = {}
        for o in self.observables:
            y = kept[o].to_numpy(float) if o in kept else np.full(len(kept), np.nan)
            self.emulators_[o] = {}
            for k in self.mode_classifier_.modes_:
                ok = np.isfinite(y) & (modes == k)
                if ok.sum() < len(b) + 2:
                    raise ValueError("the emulator of %s needs at least %d runs where it is "
                                     "finite, has %d" % (o, len(b) + 2, int(ok.sum())))
                em = GPEmulator(b, outputs=(o,), nu=2.5, trend=True,
                                log_outputs=tuple(x for x in LOG_OBSERVABLES if x == o),
                                noise_keys=CONDITION_INPUTS, n_restarts_optimizer=1,
                                random_state=self.seed, fit_cache=self.fit_cache)
                self.emulators_[o][k] = em.fit(X[ok], pd.DataFrame({o: y[ok]}))
        self.runs_ = runs.reset_index(drop=True)
        self._memo = {}
        return self

    def mode_counts(self) -> dict:
        """{mode: {"runs": n, "emulated": bool}} of the training runs: the modes with an
        emulator of their own, and the rarer ones whose runs were left out."""
        raw = (self.runs_["motion_mode"].astype(str).to_numpy() if "motion_mode" in self.runs_
               else np.full(len(self.runs_), "any"))
        used = self.mode_labels(self.runs_)
        return {str(k): {"runs": int(n), "emulated": used[raw == k][0] is not None}
                for k, n in pd.Series(raw).value_counts().items()}

    def mode_labels(self, runs: pd.DataFrame) -> np.ndarray:
        """Each run's motion mode as the emulators are split by it, None for a run left out:
        a mode with fewer runs than one emulator needs (every observable finite in at least
        ``inputs + 2`` of them) is a different motion the runs hold too few of to emulate (the
        ball at rest in a corner: f_col 0) - its runs would be outliers of the mode they joined
        - and is left out of the emulators and the classifier (listed by :meth:`mode_counts`).
        Runs without a ``motion_mode`` column are one mode."""
        raw = (runs["motion_mode"].astype(str).to_numpy() if "motion_mode" in runs
               else np.full(len(runs), "any"))
        finite = np.ones(len(runs), bool)
        for o in self.observables:
            finite &= np.isfinite(runs[o].to_numpy(float)) if o in runs else False
        need = len(self.bounds()) + 2
        counts = pd.Series(raw[finite]).value_counts()
        major = [k for k, n in counts.items() if n >= need] or list(counts.index[:1])
        return np.where(np.isin(raw, major), raw, None).astype(object)

    # ------------------------------------------------------------------ predictions
    def _inputs(self, points) -> np.ndarray:
        """Every point (a DataFrame with the space's names, or an array in their order) at
        every condition (points outer): emulator input rows in the order of :meth:`bounds`."""
        P = (points[self.space.names].to_numpy(float) if isinstance(points, pd.DataFrame)
             else np.atleast_2d(np.asarray(points, float)))
        n_c = len(self._X_cond)
        if getattr(self, "_template", None) is None:
            cols = list(self.bounds())
            self._cols = [cols.index(n) for n in self.space.names]
            t = np.zeros((n_c, len(cols)))
            for c in CONDITION_INPUTS:
                t[:, cols.index(c)] = self._X_cond[c].to_numpy(float)
            stated = self.conditions.get("amplitude_mm")
            self._stated = None
            if stated is not None and "amplitude_m" in self.space.names:
                a = stated.to_numpy(float) * 1e-3
                if np.isfinite(a).any():
                    self._stated = (cols.index("amplitude_m"), np.isfinite(a), a)
            self._template = t
        X = np.tile(self._template, (len(P), 1))
        X[:, self._cols] = np.repeat(P, n_c, axis=0)
        if self._stated is not None:
            j, ok, a = self._stated
            okk = np.tile(ok, len(P))
            X[okk, j] = np.tile(a, len(P))[okk]
        return X

    def mode_parts(self, points, corr=True):
        """Each emulated mode's predictions and the modes' probabilities: ({mode: {observable:
        Prediction of shape (n_points, n_conditions) with ``latent_corr`` (n_points,
        n_conditions, n_conditions), None with ``corr=False``}}, p of shape (n_points,
        n_conditions, n_modes)), the modes in the order of the classifier's ``modes_``. The
        means and sds do not depend on ``corr``: a search over many points that reads only
        them skips the correlations (a fifth of a loop's time)."""
        X = self._inputs(points)
        n_c = len(self._X_cond)
        n_p = len(X) // n_c
        per = {k: {} for k in self.mode_classifier_.modes_}
        for o, ems in self.emulators_.items():
            for k, em in ems.items():
                p = em.predict_parts(X, block=n_c if corr else None)
                per[k][o] = Prediction(*(a[:, 0].reshape(n_p, n_c)
                                         for a in (p.mean, p.latent_sd, p.chaos_sd)),
                                       latent_corr=p.latent_corr[:, 0] if corr else None)
        P = self.mode_classifier_.predict_proba(X).reshape(n_p, n_c, -1)
        for c, k in self._stated_index().items():
            P[:, c, :] = 0.0
            P[:, c, k] = 1.0
        return per, P

    def stated_modes(self) -> dict:
        """{condition_id: mode} the dataset states (conditions' ``motion_mode``: seen in the
        film), the mode None where the model does not emulate it (too few runs in it) - then
        the classifier's p holds there."""
        col = self.conditions.get("motion_mode")
        if col is None:
            return {}
        modes = (list(self.mode_classifier_.modes_) if hasattr(self, "mode_classifier_")
                 else [])
        return {cid: (m if m in modes else None)
                for cid, m in zip(self.conditions["condition_id"], col.fillna("").astype(str))
                if m}

    def _stated_index(self) -> dict:
        """{condition index: mode index} of the stated modes the model emulates."""
        if self.conditions.get("motion_mode") is None:
            return {}
        modes = list(self.mode_classifier_.modes_)
        cids = list(self.conditions["condition_id"])
        return {cids.index(c): modes.index(m) for c, m in self.stated_modes().items()
                if m is not None}

    @staticmethod
    def _mixed(per, P) -> dict:
        """{observable: Prediction of shape (n_points, n_conditions)} of the modes' mixture
        (:func:`analysis.emulator.mix_modes`) from :meth:`mode_parts`."""
        modes = list(per)
        n_p, n_c, _ = P.shape
        out = {}
        for o in per[modes[0]]:
            parts = [per[k][o] for k in modes]
            if len(parts) == 1:
                out[o] = parts[0]
            else:
                corr = parts[0].latent_corr is not None
                flat = [Prediction(*(a.reshape(-1, 1) for a in (q.mean, q.latent_sd,
                                                                   q.chaos_sd)),
                                   latent_corr=q.latent_corr[:, None] if corr else None)
                        for q in parts]
                p = mix_modes(flat, P.reshape(n_p * n_c, -1), block=n_c if corr else None)
                out[o] = Prediction(*(a[:, 0].reshape(n_p, n_c)
                                      for a in (p.mean, p.latent_sd, p.chaos_sd)),
                                    latent_corr=p.latent_corr[:, 0] if corr else None,
                                    mode_dev=p.mode_dev[:, 0].reshape(n_p, n_c, -1))
        return out

    def dem_parts(self, points, corr=True) -> dict:
        """{observable: Prediction of shape (n_points, n_conditions)} of the modes' mixture
        (``corr=False``: no ``latent_corr``)."""
        return self._mixed(*self.mode_parts(points, corr=corr))

    def point_vector(self, theta, effects=None) -> np.ndarray:
        """One design point as an array in the order of ``space.names`` (base parameters from
        ``theta``, the rest theta_ref's; DEM effect strengths of the space, others ignored)."""
        v = [float(theta.get(n, self.theta_ref[n])) for n in self.space.base_names]
        eff = {effect_input(k): float(s) for k, s in (effects or {}).items()}
        v += [eff.get(n, 0.0) for n in self.space.effect_names]
        return np.array(v)

    def point(self, theta, effects=None) -> pd.DataFrame:
        """One design point (a one-row DataFrame of the space's names)."""
        return pd.DataFrame([self.point_vector(theta, effects)], columns=self.space.names)

    def _modes_at(self, theta, effects):
        """:meth:`mode_parts` at one point, remembered (a fit asks for the mean and the sd
        at the same point, one after the other): (per-mode parts, p of shape (1, n_c, K),
        the mixture's parts or None until asked)."""
        v = self.point_vector(theta, effects)
        key = v.tobytes()
        hit = self._memo.get(key)
        if hit is None:
            if len(self._memo) >= 512:
                self._memo.clear()
            hit = self._memo[key] = [*self.mode_parts(v[None, :]), None]
        return hit

    def _parts_at(self, theta, effects):
        """The modes' mixture (:meth:`dem_parts`, with sds) at one point, remembered."""
        hit = self._modes_at(theta, effects)
        if hit[2] is None:
            hit[2] = self._mixed(hit[0], hit[1])
        return hit[2]

    def prefetch(self, pairs):
        """Emulate many points at once and remember them: ``pairs`` of (theta, effects) that
        fits will ask for next (a finite-difference Jacobian's k + 1 nearby points) go through
        each emulator in one call instead of k + 1."""
        keys, vs = [], []
        for theta, effects in pairs:
            v = self.point_vector(theta, effects)
            k = v.tobytes()
            if k not in self._memo and k not in keys:
                keys.append(k)
                vs.append(v)
        if not vs:
            return
        if len(self._memo) + len(vs) > 512:
            self._memo.clear()
        per, P = self.mode_parts(np.vstack(vs))
        for i, k in enumerate(keys):
            one = {m: {o: Prediction(q.mean[i:i + 1], q.latent_sd[i:i + 1],
                                     q.chaos_sd[i:i + 1], q.latent_corr[i:i + 1])
                       for o, q in d.items()} for m, d in per.items()}
            self._memo[k] = [one, P[i:i + 1], None]

    def mode_components(self, theta, effects=None) -> ModeComponents:
        """The twin's response at one point per emulated motion mode - each mode's mean and
        its emulator's covariance by self.keys (as :meth:`predict` and :meth:`model_cov` give
        the mixture's), and each condition's log p(mode): the likelihood's mixture, which a
        fit scores per condition in the mode the data make most probable
        (:class:`analysis.diagnose.Problem`)."""
        self._check_effects(effects)
        per, P, _ = self._modes_at(theta, effects)
        means = [self._assemble(per[k], theta, effects, "mean") for k in per]
        covs = [self._latent_cov(per[k], theta, effects) for k in per]
        return ModeComponents(modes=tuple(per), keys=self.keys, mean=np.stack(means),
                              cov=np.stack(covs),
                              log_p=np.log(np.clip(P[0].T, 1e-300, 1.0)),
                              condition=self._key_condition)

    def _assemble(self, parts, theta, effects, which):
        """An array in the order of self.keys of ``which`` ('mean', 'latent_sd', 'chaos_sd') at
        one point; yields (and their sds, propagated through E_tot) from the speed and rate."""
        v_col = SPEED_COLUMN[self.velocity_frame]
        direct, d_row, d_col, y_pos, y_col, y_t = self._lay
        table = np.vstack([getattr(parts[o], which)[0]
                           for o in (v_col, "f_col_hz") + self.flight_obs])
        out = np.empty(len(self.keys))
        out[direct] = table[d_row, d_col]
        fac = self._observed(parts, effects)
        if fac is not None:
            out[direct] *= fac[d_row, d_col]
        if len(y_pos):
            eff_obj, slope, intercept = self._kinetics(theta, effects)
            v_m = parts[v_col].mean[0][y_col]
            f_m = parts["f_col_hz"].mean[0][y_col]
            m = self.mass_kg[y_col]
            e_kin = 0.5 * m * v_m ** 2
            if which == "mean":
                out[y_pos] = (slope * e_kin * f_m * y_t / 1000.0 + intercept if eff_obj is None
                              else eff_obj.yield_pct(e_kin, f_m, y_t, slope, intercept))
            else:
                v_s = getattr(parts[v_col], which)[0][y_col]
                f_s = getattr(parts["f_col_hz"], which)[0][y_col]
                out[y_pos] = abs(slope) * y_t / 1000.0 * np.hypot(m * v_m * f_m * v_s,
                                                                  e_kin * f_s)
        return out

    def _latent_cov(self, parts, theta, effects):
        """The emulator's covariance of the twin's mean response between every pair of
        observations (self.keys' order) at one point: each emulated observable's errors at the
        conditions correlated as its GP says (one smooth response), the observables'
        emulators independent of one another, carried to the yields through E_tot to first
        order (the same propagation as their sd). Its diagonal is ``latent_sd`` squared."""
        v_col = SPEED_COLUMN[self.velocity_frame]
        direct, d_row, d_col, y_pos, y_col, y_t = self._lay
        names = (v_col, "f_col_hz") + self.flight_obs
        n_c = len(self._X_cond)
        blocks = []
        for o in names:
            sd = parts[o].latent_sd[0]
            blocks.append(parts[o].latent_corr[0] * np.outer(sd, sd))
        J = np.zeros((len(self.keys), len(names) * n_c))
        fac = self._observed(parts, effects)
        J[direct, d_row * n_c + d_col] = 1.0 if fac is None else fac[d_row, d_col]
        if len(y_pos):
            _, slope, _ = self._kinetics(theta, effects)
            v_m = parts[v_col].mean[0][y_col]
            f_m = parts["f_col_hz"].mean[0][y_col]
            m = self.mass_kg[y_col]
            J[y_pos, y_col] = slope * y_t / 1000.0 * m * v_m * f_m
            J[y_pos, n_c + y_col] = slope * y_t / 1000.0 * 0.5 * m * v_m ** 2
        S = np.zeros((J.shape[1], J.shape[1]))
        for i, b in enumerate(blocks):
            S[i * n_c:(i + 1) * n_c, i * n_c:(i + 1) * n_c] = b
        if parts[v_col].mode_dev is not None:
            # one run is in one mode for all its observables: the modes' spread at a condition
            # moves them together (its diagonal is already in each observable's block)
            for c in range(n_c):
                D = np.array([parts[o].mode_dev[0, c] for o in names])
                B = D @ D.T
                np.fill_diagonal(B, 0.0)
                idx = np.arange(len(names)) * n_c + c
                S[np.ix_(idx, idx)] += B
        return J @ S @ J.T

    def _observed(self, parts, effects):
        """(stacked observables x conditions) factors of the observation effects: those the
        dataset pins (:attr:`pinned`) and those switched on in ``effects``; None without any
        (the hot path: most predictions have none). The measurement chain reports the twin's
        value times this; the yields (the chemistry sees the true speed) are not touched."""
        on = [k for k, v in (effects or {}).items() if k in self.observation and v]
        if not on and not self._pinned_objs:
            return None
        from effects import load_effects
        objs = list(self._pinned_objs) + [
            load_effects(self.observation[k].spec(effects[k]), side="observation")[0]
            for k in on]
        names = ("v_mean_m_s", "f_col_hz") + self.flight_obs
        fac = np.ones((len(names), len(self._X_cond)))
        f_col = parts["f_col_hz"].mean[0]
        # the twin's state per condition, for factors that need more than f_col (keywords of
        # the module's observed_factor; effects.base.ObservationEffect)
        state = {"v_mean_m_s": parts[SPEED_COLUMN[self.velocity_frame]].mean[0],
                 "frequency_hz": self._X_cond["frequency_hz"].to_numpy(float),
                 "ball_diameter_m": self._X_cond["ball_diameter_m"].to_numpy(float)}
        state.update({o: parts[o].mean[0] for o in self.flight_obs})
        for e in objs:
            for j, o in enumerate(names):
                fac[j] *= e.factor_of(o, f_col, **state)
        return fac

    @property
    def _kin(self):
        if getattr(self, "_kin_cands", None) is None:
            from analysis.catalog import candidates
            self._kin_cands = candidates("kinetics")
        return self._kin_cands

    def _kinetics(self, theta, effects):
        from analysis.kinetics import PAPER_SLOPE_PCT_PER_KJ
        kin = self._kin
        on = [k for k, s in (effects or {}).items() if k in kin and s]
        if len(on) > 1:
            raise ValueError("kinetics effects do not compose: %s" % on)
        eff_obj = None
        if on:
            from effects import load_effects
            eff_obj = load_effects(kin[on[0]].spec(effects[on[0]]), side="kinetics")[0]
        return (eff_obj, float(theta.get("slope_pct_per_kj", PAPER_SLOPE_PCT_PER_KJ)),
                float(theta.get("intercept_pct", 0.0)))

    def _check_effects(self, effects):
        kin = self._kin
        unknown = [k for k in (effects or {}) if effect_input(k) not in self.space.effect_names
                   and k not in kin and k not in self.observation]
        if unknown:
            raise ValueError("unknown effect(s) %s" % unknown)

    def predict(self, theta, effects=None) -> pd.Series:
        """The twin's mean response by (condition_id, observable)."""
        self._check_effects(effects)
        return pd.Series(self._assemble(self._parts_at(theta, effects), theta, effects,
                                        "mean"), index=self.keys, dtype=float)

    def model_se(self, theta=None, effects=None) -> pd.Series:
        """The emulator's sd of the twin's mean response at ``theta`` (default theta_ref): the
        square root of :meth:`model_cov`'s diagonal (a yield's carries the covariance of the
        speed and the rate that the motion modes' spread gives them)."""
        return pd.Series(np.sqrt(np.maximum(np.diag(self.model_cov(theta, effects)), 0.0)),
                         index=self.keys)

    def model_cov(self, theta=None, effects=None) -> np.ndarray:
        """The emulator's covariance of the twin's mean response at ``theta`` (default
        theta_ref) between the observations, an (n, n) array in the order of ``self.keys`` (the
        index of :meth:`predict`): :meth:`model_se` squared on its diagonal, and the
        correlation of one emulator's errors across the conditions off it."""
        theta = dict(theta or self.theta_ref)
        return self._latent_cov(self._parts_at(theta, effects), theta, effects)

    def chaos_sd(self, theta=None, effects=None) -> pd.Series:
        """One twin run's scatter about its mean at ``theta`` (default theta_ref) with the DEM
        ``effects`` on."""
        theta = dict(theta or self.theta_ref)
        parts = self.dem_parts(self.point(theta, effects))
        return pd.Series(self._assemble(parts, theta, None, "chaos_sd"), index=self.keys,
                         dtype=float)

    def flight_run_sd(self) -> pd.Series:
        """One run's chaos of the impact observables per (condition, observable)."""
        sd = self.chaos_sd()
        keep = [k for k in sd.index if k[1] in self.flight_obs]
        return sd.loc[keep]

    # ------------------------------------------------------------- loop's parameters
    @property
    def has_yields(self):
        return any(self.yield_times_min.values())

    def base_params(self):
        """diagnose BaseParameters: the design's base parameters over their priors (starting
        at theta_ref) and, with yields, the powder line's slope and intercept."""
        from analysis import kinetics
        from analysis.diagnose import BaseParameter
        out = [BaseParameter(p.name, float(np.clip(self.theta_ref[p.name], *p.prior)),
                             *map(float, p.prior)) for p in self.space.base]
        if self.has_yields:
            from analysis.parameter_space import KINETICS_LINE
            start = {"slope_pct_per_kj": kinetics.PAPER_SLOPE_PCT_PER_KJ,
                     "intercept_pct": kinetics.PAPER_INTERCEPT_PCT}
            out += [BaseParameter(k, start[k], lo, hi)
                    for k, (_, lo, hi) in KINETICS_LINE.items()]
        return out

    def effects(self):
        """diagnose Effects: the design's DEM candidates over [0, s_max], with yields the
        kinetics candidates, and the observation effects asked for."""
        from analysis.diagnose import Effect
        from analysis.catalog import candidates
        cands = list(self.space.effects)
        if self.has_yields:
            cands += list(candidates("kinetics").values())
        cands += list(self.observation.values())
        return [Effect(c.name, 0.0, float(c.s_max), null=0.0, kind=c.kind,
                       description="strength = %s" % c.strength_label) for c in cands]

    def prior_observations(self) -> pd.DataFrame:
        """No pseudo-observations: the priors bound the design, the data pin what they can."""
        return pd.DataFrame(columns=["condition_id", "observable", "value", "sd"])


# --------------------------------------------------------------------------- waves

def observation_table(model: EmulatedTwin, observations: pd.DataFrame) -> pd.DataFrame:
    """The observations the emulators predict (speed, f_col, impact observables: not yields),
    with value and sd, in the order of :func:`stacked_prediction`'s columns."""
    keys = [k for k in model.keys if not k[1].startswith("yield")]
    obs = observations.set_index(["condition_id", "observable"])
    missing = [k for k in keys if k not in obs.index]
    if missing:
        raise ValueError("observations lack %r" % (missing[0],))
    return obs.loc[keys, ["value", "sd"]].reset_index()


def stacked_prediction(model: EmulatedTwin, points: pd.DataFrame) -> Prediction:
    """Prediction of shape (n_points, n_obs) at the observations of :func:`observation_table`
    (means and sds; no correlations)."""
    parts = model.dem_parts(points, corr=False)
    cids = list(model.conditions["condition_id"])
    v_col = SPEED_COLUMN[model.velocity_frame]
    cols = []
    for k in model.keys:
        if k[1].startswith("yield"):
            continue
        col = v_col if k[1] == "v_mean_m_s" else k[1]
        cols.append((col, cids.index(k[0])))
    return Prediction(*(np.column_stack([getattr(parts[o], a)[:, i] for o, i in cols])
                        for a in ("mean", "latent_sd", "chaos_sd")))


def wave_points(model: EmulatedTwin, observations, existing, n_points, seed, *,
                obs_chaos_runs=1.0, rotate=0):
    """The next wave: half its points where the data are plausible with no effect, the rest
    split over the candidate effects (each free in turn; ``rotate`` - the wave's number -
    shifts which effects come first, so that waves with fewer points than effects reach them
    all). Returns (points, {free effect or 'none': fraction not ruled out})."""
    space = model.space
    obs = observation_table(model, observations)
    groups = [None] + [c.name for c in space.effects]
    share = [max(1, n_points // 2)] + [0] * len(space.effects)
    rest = n_points - share[0]
    if not space.effects:
        share[0], rest = n_points, 0
    for k in range(rest):
        share[1 + (k + rotate * rest) % len(space.effects)] += 1
    new, fracs = [], {}
    have = existing
    for g, n in zip(groups, share):
        if n <= 0:
            continue
        pts, frac = next_wave(space, lambda c: stacked_prediction(model, c), obs, have, n,
                              seed=seed + len(new), effects=None if g is None else [g],
                              obs_chaos_runs=obs_chaos_runs)
        fracs[g or "none"] = frac
        new.append(pts)
        have = pd.concat([have, pts], ignore_index=True)
    out = pd.concat(new, ignore_index=True)
    start = int(existing["point"].max()) + 1 if len(existing) else 0
    out.insert(0, "point", np.arange(start, start + len(out)))
    return out, fracs


def wave_runs(n_conditions, *, n_initial, n_waves, per_wave, replicates=3) -> dict:
    """How many twin runs the waves make at most: {'wave 0', 'refinement', 'total'}."""
    w0 = (int(n_initial) + int(replicates)) * int(n_conditions)
    ref = int(n_waves) * int(per_wave) * int(n_conditions)
    return {"wave 0": w0, "refinement": ref, "total": w0 + ref}


def emulator_share(model: EmulatedTwin, observations, points) -> np.ndarray:
    """Per point, the largest ratio over the observations of the emulator's sd of the twin's
    mean to the observation's sd: below 0.5 the emulator adds less than 12 % to any sigma."""
    obs = observation_table(model, observations)
    p = stacked_prediction(model, points)
    return np.max(p.latent_sd / np.maximum(obs["sd"].to_numpy(float)[None], 1e-30), axis=1)


#: seeds of the reference point's replicates (the twin's chaos per condition)
REFERENCE_SEED0 = 500


def wave0_runs(model: EmulatedTwin, n_initial, replicates=3, seed=0, base_config=None,
               replicate_seed0=REFERENCE_SEED0):
    """(points, runs) of wave 0: the space-filling design at seed ``seed`` and the reference
    point ``model.theta_ref`` (point -1) with seeds from ``replicate_seed0``."""
    space = model.space
    pts = initial_design(space, n_initial, seed)
    ref = model.point(model.theta_ref)
    ref.insert(0, "point", -1)
    runs = pd.concat([design_runs(space, pts, model.conditions, seeds=(seed,),
                                  base_config=base_config),
                      design_runs(space, ref, model.conditions,
                                  seeds=range(replicate_seed0, replicate_seed0 + replicates),
                                  base_config=base_config)], ignore_index=True)
    return pts, runs


def build_in_waves(model: EmulatedTwin, observations, simulate, *, n_initial, n_waves,
                   per_wave, replicates=3, seed=0, base_config=None, log=print,
                   obs_chaos_runs=1.0, stop_share=None, best=None,
                   replicate_seed0=REFERENCE_SEED0):
    """Run wave 0 and up to ``n_waves`` refinement waves through ``simulate(runs) -> runs``
    (adds the observables to a table of configs, e.g. the twin through the sweep); fit
    ``model`` after each. With ``stop_share`` and ``best`` (callable(model) -> points, e.g. the
    calibrated point and each candidate's best fit) the waves stop once the emulator's share of
    the uncertainty there (:func:`emulator_share`) is below ``stop_share`` at every point.
    The reference point ``model.theta_ref`` runs with seeds from ``replicate_seed0`` (the
    chaos); every design point with seed ``seed`` (wave w: ``seed + w``).
    Returns (model, points, {wave: fractions not ruled out})."""
    space = model.space
    pts, runs = wave0_runs(model, n_initial, replicates, seed, base_config, replicate_seed0)
    runs["wave"] = 0
    log("wave 0: %d points + the reference point x %d seeds, %d runs"
        % (len(pts), replicates, len(runs)))
    runs = simulate(runs)
    model.fit(runs)
    history = {}
    for w in range(1, n_waves + 1):
        if stop_share is not None and best is not None:
            share = emulator_share(model, observations, best(model))
            if np.all(share < stop_share):
                log("waves end after wave %d: the emulator's sd is %.2f of the data's at most "
                    "where the fits lie" % (w - 1, float(np.max(share))))
                break
        new, fracs = wave_points(model, observations, pts, per_wave, seed + 17 * w,
                                 obs_chaos_runs=obs_chaos_runs, rotate=w - 1)
        history[w] = fracs
        log("wave %d: %d points; not ruled out: %s" % (w, len(new), ", ".join(
            "%s %.1f %%" % (k, 100 * v) for k, v in fracs.items())))
        r = design_runs(space, new, model.conditions, seeds=(seed + w,),
                        base_config=base_config)
        r["wave"] = w
        runs = pd.concat([runs, simulate(r)], ignore_index=True)
        pts = pd.concat([pts, new], ignore_index=True)
        model.fit(runs)
    return model, pts, history
