"""Waves of one design over the twin's inputs: space-filling first, then where the data's
plausible region lies and the emulator is unsure (history matching).

The inputs are the base parameters (:data:`analysis.parameter_space.SPACE`, over their prior
ranges) and the candidate effects' strengths (each over [0, s_max] of its catalog entry), at a
dataset's conditions. A **design point** is one vector of these; it is run at every condition
(one seed per condition by default, the same seed across conditions), so that every run of the
twin made for a dataset is a training run of one emulator (:class:`analysis.emulator.
GPEmulator` with the conditions' physics among its inputs).

* :func:`initial_design` - wave 0: a Latin hypercube over the base parameters; a share of the
  points also switches ONE candidate effect on at a strength drawn from its range (each effect
  in turn), so that every effect's response is learned jointly with the base parameters - at
  other restitutions, strokes and frictions than one anchor's;
* :func:`implausibility` - Vernon, Goldstein & Bower (2010):
  ``I = |z - E[f(x)]| / sqrt(Var_obs + Var_emulator + Var_chaos)`` per observation, where the
  chaos term is the scatter of the twin about its mean that the observation carries (one twin
  realisation of a blind dataset, or none for a measured mean whose sd already holds it);
* :func:`not_ruled_out` - the points whose largest (or ``which``-th largest) implausibility over
  the observations is below the cut-off (3, Pukelsheim's three-sigma rule);
* :func:`next_wave` - the next design points: drawn from the not-ruled-out part of a large
  candidate sample, spread by greedy maximin in the scaled inputs and weighted towards where
  the emulator is least sure;
* :func:`posterior_cloud` - a focus wave: design points drawn where a fit's posterior lies
  (its Gaussian approximation, widened), with the effects it found on - the last wave of
  history matching, run once the model is chosen.

References
----------
Vernon, I., Goldstein, M. & Bower, R. G. (2010). Galaxy formation: a Bayesian uncertainty
analysis. Bayesian Analysis 5, 619.
Andrianakis, I. et al. (2015). Bayesian history matching of complex infectious disease models
using emulation. PLoS Comput. Biol. 11, e1003968.
Pukelsheim, F. (1994). The three sigma rule. The American Statistician 48, 88.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.stats import qmc

from analysis.parameter_space import SPACE

#: implausibility cut-off (three-sigma rule, any unimodal distribution: >= 95 % inside)
CUTOFF = 3.0
#: share of wave-0 points that switch one candidate effect on
EFFECT_SHARE = 0.5
#: fewest surviving candidates before a wave refocuses; centres and width of the cloud
REFOCUS_MIN, REFOCUS_CENTRES, REFOCUS_SD = 64, 16, 0.03
#: prefix of an effect strength's input name
EFFECT_PREFIX = "effect:"
#: a focus wave's cloud (:func:`posterior_cloud`): the fit's standard errors scaled by this,
#: and the sd [fraction of the range] of a parameter whose standard error is unknown
FOCUS_SCALE, FOCUS_MIN_SD = 2.0, 0.05


def effect_input(name: str) -> str:
    """The emulator input name of an effect's strength."""
    return EFFECT_PREFIX + name


@dataclass(frozen=True)
class DesignSpace:
    """The inputs a design moves: base parameters over their priors, effects over [0, s_max].

    base : tuple of analysis.parameter_space.Parameter
    effects : tuple of catalog candidates (analysis.catalog.Candidate: name, s_max,
        spec(s), strength_label)
    """
    base: tuple
    effects: tuple = ()

    @classmethod
    def of(cls, base_names, effects=(), priors=None):
        """The space of the named base parameters (declared in parameter_space) and effects;
        ``priors`` {name: (lo, hi)} narrows a parameter's declared prior (``--free NAME=LO:HI``,
        checked by :func:`analysis.parameter_space.parse_free`)."""
        import dataclasses
        unknown = [n for n in base_names if n not in SPACE]
        if unknown:
            raise ValueError("not a movable parameter of the twin: %s (analysis/"
                             "parameter_space.py declares %s)" % (", ".join(unknown),
                                                                  ", ".join(SPACE)))
        pr = dict(priors or {})
        return cls(tuple(dataclasses.replace(SPACE[n], prior=tuple(pr[n])) if n in pr
                         else SPACE[n] for n in base_names), tuple(effects))

    @property
    def base_names(self):
        return [p.name for p in self.base]

    @property
    def effect_names(self):
        return [effect_input(c.name) for c in self.effects]

    @property
    def names(self):
        return self.base_names + self.effect_names

    def bounds(self) -> dict:
        """{input name: (lower, upper)}: base priors, then effect strength ranges."""
        out = {p.name: tuple(map(float, p.prior)) for p in self.base}
        out.update({effect_input(c.name): (0.0, float(c.s_max)) for c in self.effects})
        return out

    def scaled(self, points: pd.DataFrame) -> np.ndarray:
        """Points in the unit cube of :meth:`bounds`."""
        b = self.bounds()
        lo = np.array([v[0] for v in b.values()])
        hi = np.array([v[1] for v in b.values()])
        return (points[list(b)].to_numpy(float) - lo) / (hi - lo)

    def effects_config(self, point) -> dict:
        """The run config's ``effects`` entry of a design point (the effects with strength > 0)."""
        out = {}
        for c in self.effects:
            s = float(point[effect_input(c.name)])
            if s > 0:
                out.update(c.spec(s))
        return out

    def theta(self, point) -> dict:
        """{base parameter: value} of a design point."""
        return {n: float(point[n]) for n in self.base_names}


def initial_design(space: DesignSpace, n_points: int, seed: int,
                   effect_share: float = EFFECT_SHARE) -> pd.DataFrame:
    """Wave 0: ``n_points`` design points (columns :meth:`DesignSpace.names`).

    The base parameters fill a scrambled Latin hypercube of the prior box (scipy.stats.qmc,
    optimised for centred discrepancy); the last ``round(effect_share * n_points)`` points
    switch one effect on, the effects taken in turn, the strength from one more Latin-hypercube
    column over (0, s_max] (so each effect's strengths spread over its range).
    """
    if n_points < 1:
        raise ValueError("a design needs at least one point, got %d" % n_points)
    if not 0.0 <= effect_share <= 1.0:
        raise ValueError("effect_share must lie in [0, 1], got %g" % effect_share)
    d = len(space.base)
    u = qmc.LatinHypercube(d=d + 1, rng=np.random.default_rng(seed),
                           optimization="random-cd").random(n_points)
    b = space.bounds()
    pts = pd.DataFrame({n: b[n][0] + u[:, i] * (b[n][1] - b[n][0])
                        for i, n in enumerate(space.base_names)})
    for n in space.effect_names:
        pts[n] = 0.0
    n_eff = int(round(effect_share * n_points)) if space.effects else 0
    for k, i in enumerate(range(n_points - n_eff, n_points)):
        c = space.effects[k % len(space.effects)]
        pts.loc[i, effect_input(c.name)] = float(c.s_max) * max(u[i, d], 0.02)
    pts.insert(0, "point", np.arange(n_points))
    pts["wave"] = 0
    return pts


def implausibility(mean, latent_sd, chaos_sd, obs, obs_sd, obs_chaos_runs=1.0):
    """Implausibility of each candidate point at each observation.

    Parameters
    ----------
    mean, latent_sd, chaos_sd : ndarray (n_points, n_obs) - the emulator's prediction of the
        twin at each point (analysis.emulator.Prediction at every observation's condition)
    obs, obs_sd : ndarray (n_obs,) - the observations and their measurement sds
    obs_chaos_runs : float - how many twin realisations each observation averages (1: a blind
        dataset made from one realisation; np.inf: a measured mean whose sd holds the scatter)

    Returns
    -------
    ndarray (n_points, n_obs)
    """
    chaos = 0.0 if np.isinf(obs_chaos_runs) else chaos_sd ** 2 / float(obs_chaos_runs)
    var = np.asarray(obs_sd, float)[None] ** 2 + latent_sd ** 2 + chaos
    return np.abs(np.asarray(obs, float)[None] - mean) / np.sqrt(var)


def not_ruled_out(imp, cutoff=CUTOFF, which=1):
    """Mask of points whose ``which``-th largest implausibility is below ``cutoff`` (which=2
    or 3 guards against one observation the emulator gets wrong, Vernon et al. 2010)."""
    imp = np.asarray(imp, float)
    k = min(int(which), imp.shape[1])
    kth = -np.sort(-imp, axis=1)[:, k - 1]
    return kth < cutoff


def candidate_sample(space: DesignSpace, n: int, seed: int, effects=None) -> pd.DataFrame:
    """``n`` uniform (Sobol) points of the base box, with the effects in ``effects`` (names)
    also uniform over their ranges and every other effect off."""
    eff = list(effects or [])
    unknown = [e for e in eff if effect_input(e) not in space.effect_names]
    if unknown:
        raise ValueError("not an effect of the design space: %s" % ", ".join(unknown))
    names = space.base_names + [effect_input(e) for e in eff]
    b = space.bounds()
    m = int(np.ceil(np.log2(max(n, 2))))
    u = qmc.Sobol(d=len(names), rng=np.random.default_rng(seed)).random_base2(m)[:n]
    pts = pd.DataFrame({k: b[k][0] + u[:, i] * (b[k][1] - b[k][0])
                        for i, k in enumerate(names)})
    for k in space.effect_names:
        if k not in pts:
            pts[k] = 0.0
    return pts[space.names]


def maximin_pick(pool: np.ndarray, existing: np.ndarray, n: int, weight=None) -> list:
    """Indices of ``n`` rows of ``pool`` (unit-cube points) picked greedily, each the farthest
    from the existing and the already picked ones (the distance times ``weight`` when given,
    e.g. the emulator's sd there)."""
    if n <= 0 or not len(pool):
        return []
    w = np.ones(len(pool)) if weight is None else np.asarray(weight, float)
    if len(existing):
        dmin = np.min(np.linalg.norm(pool[:, None, :] - existing[None], axis=2), axis=1)
    else:
        dmin = np.full(len(pool), np.inf)
    picked = []
    for _ in range(min(n, len(pool))):
        score = np.where(np.isinf(dmin), w, dmin * w)
        score[picked] = -np.inf
        i = int(np.argmax(score))
        picked.append(i)
        dmin = np.minimum(dmin, np.linalg.norm(pool - pool[i], axis=1))
    return picked


def next_wave(space: DesignSpace, predict, observations, existing: pd.DataFrame, n_points: int,
              seed: int, *, effects=None, n_candidates=4096, cutoff=CUTOFF, which=1,
              obs_chaos_runs=1.0):
    """The next wave's design points and what the current emulator rules out.

    Parameters
    ----------
    space : DesignSpace
    predict : callable(points DataFrame) -> analysis.emulator.Prediction of shape
        (n_points, n_obs), the twin at every observation (condition x observable)
    observations : DataFrame with columns value, sd (one row per observation, the order of
        ``predict``'s columns)
    existing : DataFrame - the design points run so far (columns space.names)
    n_points : int - how many to pick
    seed : int
    effects : names of the effects free in this wave (None: none)
    n_candidates, cutoff, which, obs_chaos_runs : see :func:`candidate_sample`,
        :func:`not_ruled_out`, :func:`implausibility`

    Returns
    -------
    (DataFrame of the new points, float - fraction of the candidates not ruled out)
    """
    cand = candidate_sample(space, n_candidates, seed, effects)
    obs, obs_sd = observations["value"].to_numpy(float), observations["sd"].to_numpy(float)

    def score(c):
        p = predict(c)
        i = implausibility(p.mean, p.latent_sd, p.chaos_sd, obs, obs_sd, obs_chaos_runs)
        return p, i

    pred, imp = score(cand)
    keep = not_ruled_out(imp, cutoff, which)
    frac = float(keep.mean())
    if keep.sum() < max(REFOCUS_MIN, 4 * n_points):
        # too few uniform candidates survive (a parameter the data pin sharply): refocus on a
        # cloud about the least implausible ones, so that the wave's points come from the
        # plausible region, not from the edge of what was ruled out
        cloud = refocus_sample(space, cand, np.max(imp, axis=1), n_candidates, seed, effects)
        p2, i2 = score(cloud)
        cand = pd.concat([cand, cloud], ignore_index=True)
        pred = type(pred)(*(np.vstack([a, b]) for a, b in zip(
            (pred.mean, pred.latent_sd, pred.chaos_sd), (p2.mean, p2.latent_sd, p2.chaos_sd))))
        imp = np.vstack([imp, i2])
        keep = not_ruled_out(imp, cutoff, which)
    order = np.argsort(np.max(imp, axis=1))
    idx = np.flatnonzero(keep) if keep.sum() >= n_points else order[:max(64, n_points)]
    pool = cand.iloc[idx]
    # weight: the emulator's largest sd relative to the observations' (where it is unsure)
    sd_rel = pred.latent_sd[idx] / np.maximum(obs_sd[None], 1e-30)
    w = np.max(sd_rel, axis=1)
    w = 0.5 + w / max(float(np.max(w)), 1e-30)
    picked = maximin_pick(space.scaled(pool), space.scaled(existing), n_points, w)
    new = pool.iloc[picked].reset_index(drop=True)
    return new, frac


def refocus_sample(space: DesignSpace, cand: pd.DataFrame, imp_max, n, seed, effects=None):
    """``n`` points in a Gaussian cloud (sd :data:`REFOCUS_SD` of each range) about the
    :data:`REFOCUS_CENTRES` candidates of lowest largest implausibility, clipped to the box;
    effects outside ``effects`` stay off."""
    rng = np.random.default_rng(seed + 7919)
    free = space.base_names + [effect_input(e) for e in (effects or [])]
    b = space.bounds()
    centres = cand.iloc[np.argsort(imp_max)[:REFOCUS_CENTRES]]
    k = rng.integers(0, len(centres), n)
    out = pd.DataFrame({c: np.zeros(n) for c in space.names})
    for c in free:
        lo, hi = b[c]
        x = centres[c].to_numpy(float)[k] + REFOCUS_SD * (hi - lo) * rng.standard_normal(n)
        out[c] = np.clip(x, lo, hi)
    return out[space.names]


def posterior_cloud(space: DesignSpace, centre: dict, cov: pd.DataFrame, n_points: int,
                    seed: int, *, scale: float = FOCUS_SCALE, spread=(),
                    ridge=None) -> pd.DataFrame:
    """``n_points`` design points where a fit's posterior lies (a focus wave).

    A Latin hypercube in whitened coordinates mapped through the fit's Gaussian approximation
    N(centre, scale^2 cov) over the inputs ``cov`` names that the space holds (the base
    parameters fitted, the strengths of the effects found, named by :func:`effect_input`),
    the correlations kept. Every other input sits at ``centre``'s value (an effect
    not in ``centre`` is off). A standard error that is not finite or zero (a parameter on a
    bound) counts as :data:`FOCUS_MIN_SD` of its range; none is wider than half its range (a
    direction the data do not pin spreads over the box); points are clipped to the box.

    The inputs named in ``spread`` (an effect's strength) are not drawn from the Gaussian but
    stratified over their whole range (one column of the Latin hypercube each), so that the
    wave measures the twin's response to them where the fit does not believe the answer lies
    too: an emulator wrong about an effect's strength cannot be corrected by runs about its own
    wrong answer. The other inputs keep their Gaussian (their marginal without the spread ones).

    ``ridge`` (a callable: DataFrame of the spread inputs' values -> DataFrame of other inputs)
    moves each point's centre to where the data are plausible at its spread values - the base
    parameters profiled at that strength - and the Gaussian about it is then the conditional
    one (given the spread inputs): the wave follows the ridge of a strength traded against the
    base parameters instead of the fit's tangent to it, so the emulator learns the ridge where
    its stated sd would otherwise pull every later fit back to the runs it has.

    Returns
    -------
    DataFrame (columns :meth:`DesignSpace.names`)
    """
    from scipy.stats import norm
    if n_points < 1:
        return pd.DataFrame(columns=space.names)
    b = space.bounds()
    spread = list(spread)
    unknown = [k for k in list(centre) + spread if k not in b]
    if unknown:
        raise ValueError("posterior_cloud: not inputs of the design space: %s" % unknown)
    free = [k for k in cov.index if k in b and k not in spread]
    lo = np.array([b[k][0] for k in free])
    hi = np.array([b[k][1] for k in free])
    mu = np.clip(np.array([float(centre.get(k, 0.0)) for k in free]), lo, hi)
    c = _given(cov, free, spread) if ridge is not None else cov.loc[free, free].to_numpy(float)
    sd = np.sqrt(np.clip(np.diag(c), 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = c / np.outer(sd, sd)
    corr = np.where(np.isfinite(corr), np.clip(corr, -1.0, 1.0), 0.0)
    np.fill_diagonal(corr, 1.0)
    sd = np.where(np.isfinite(sd) & (sd > 0), scale * sd, FOCUS_MIN_SD * (hi - lo))
    sd = np.minimum(sd, 0.5 * (hi - lo))
    # the nearest valid correlation (a Gauss-Newton covariance near a bound may be indefinite)
    w, v = np.linalg.eigh(corr)
    L = v * np.sqrt(np.clip(w, 1e-9, None))
    L /= np.sqrt(np.sum(L ** 2, axis=1, keepdims=True))
    pts = pd.DataFrame({k: np.full(int(n_points), float(centre.get(k, 0.0)))
                        for k in space.names})
    if free or spread:
        u = qmc.LatinHypercube(d=len(free) + len(spread),
                               rng=np.random.default_rng(seed)).random(n_points)
        z = norm.ppf(np.clip(u[:, :len(free)], 1e-6, 1 - 1e-6))
        for j, k in enumerate(spread):
            pts[k] = b[k][0] + u[:, len(free) + j] * (b[k][1] - b[k][0])
        if ridge is not None and spread:
            on = ridge(pts[spread].reset_index(drop=True))
            mu = np.column_stack([np.clip(on[k].to_numpy(float), lo[i], hi[i])
                                  if k in on else np.full(len(pts), mu[i])
                                  for i, k in enumerate(free)]) if free else mu
        x = np.clip(mu + (z @ L.T) * sd, lo, hi)
        for i, k in enumerate(free):
            pts[k] = x[:, i]
    return pts[space.names]


def _given(cov: pd.DataFrame, free, spread) -> np.ndarray:
    """The covariance of ``free`` given ``spread`` (the Gaussian's conditional; the marginal
    when ``cov`` does not name the spread inputs or their block is singular)."""
    s = [k for k in spread if k in cov.index]
    c = cov.loc[free, free].to_numpy(float)
    if not s or not free:
        return c
    c_fs = cov.loc[free, s].to_numpy(float)
    c_ss = cov.loc[s, s].to_numpy(float)
    if not (np.all(np.isfinite(c_fs)) and np.all(np.isfinite(c_ss))):
        return c
    try:
        return c - c_fs @ np.linalg.solve(c_ss, c_fs.T)
    except np.linalg.LinAlgError:
        return c


def design_runs(space: DesignSpace, points: pd.DataFrame, conditions, *, seeds=(0,),
                base_config=None, stated_stroke=True):
    """Run configs of design points at every condition x seed.

    Returns
    -------
    DataFrame with one row per run: point, condition_id, seed, config (a run config), and the
    design point's inputs.
    """
    from analysis.run_configs import condition_runs
    rows = []
    for _, pt in points.iterrows():
        for r in condition_runs(conditions, seeds=seeds, theta=space.theta(pt),
                                base_config=base_config,
                                effects=space.effects_config(pt) or None,
                                stated_stroke=stated_stroke):
            rows.append({"point": int(pt["point"]), "condition_id": r.condition_id,
                         "seed": r.seed, "config": r.config,
                         **{n: float(pt[n]) for n in space.names}})
    return pd.DataFrame(rows)
