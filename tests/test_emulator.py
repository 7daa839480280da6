"""The one emulator and the waves of its design, against analytic truth.

The truth here is a twin-like function that is NOT the emulator's own form: a smooth response
with an effect whose size depends on the base parameter, chaos-like noise whose size differs by
condition, and a motion-mode jump; the emulator's stated uncertainty must cover new runs as
often as it claims."""
import numpy as np
import pandas as pd
import pytest
from threadpoolctl import threadpool_limits

from analysis.emulator import GPEmulator
from analysis.history_matching import (DesignSpace, candidate_sample, effect_input,
                                       implausibility, initial_design, maximin_pick,
                                       next_wave, not_ruled_out, posterior_cloud)
from analysis.catalog import CANDIDATES

BOUNDS = {"cr": (0.1, 0.7), "s": (0.0, 1.0), "f": (20.0, 32.0)}
#: chaos sd of one run per condition (differs 3x between conditions)
CHAOS = {20.0: 0.01, 26.0: 0.02, 32.0: 0.03}


@pytest.fixture(autouse=True)
def one_blas_thread():
    with threadpool_limits(1):
        yield


def truth(cr, s, f, jump=True):
    """Mean response: smooth in (cr, f), an effect s whose size grows with cr, and a jump of
    0.08 where cr > 0.62 at the highest frequency (another motion mode)."""
    y = 1.0 + 0.8 * cr - 0.6 * cr ** 2 + 0.02 * (f - 26.0) - 0.15 * s * (0.3 + cr)
    if jump:
        y = y + 0.08 * ((cr > 0.62) & (f > 30.0))
    return y


def runs_at(X, rng, jump=True):
    f = X[:, 2]
    sd = np.vectorize(CHAOS.get)(f)
    return truth(X[:, 0], X[:, 1], f, jump) + sd * rng.standard_normal(len(X))


def design(rng, n_points=30, replicates=4):
    """Points x the 3 conditions; the first point repeated with ``replicates`` seeds."""
    pts = np.column_stack([rng.uniform(0.1, 0.7, n_points), rng.uniform(0, 1, n_points)])
    pts[: n_points // 2, 1] = 0.0                       # half the points: effect off
    rows, groups = [], []
    for i, (cr, s) in enumerate(pts):
        for f in CHAOS:
            for _ in range(replicates if i == 0 else 1):
                rows.append((cr, s, f))
                groups.append(i)
    return np.array(rows), np.array(groups)


def fitted(rng, jump=True, **kw):
    X, groups = design(rng)
    y = runs_at(X, rng, jump)
    em = GPEmulator(BOUNDS, outputs=("y",), trend=True, noise_keys=("f",), random_state=0,
                    n_restarts_optimizer=1, **kw).fit(X, y)
    return em, X, y, groups


def test_chaos_recovered_per_condition_from_replicates():
    em, *_ = fitted(np.random.default_rng(1), jump=False)
    tab = em.noise_table_.set_index("f")
    # 3 dof per condition: the pooled sd is within a factor 2 of the truth, and the 3x
    # spread between conditions is seen
    for f, sd in CHAOS.items():
        assert 0.5 * sd < tab.loc[f, "y_sd"] < 2.0 * sd, tab
    p = em.predict_parts(np.array([[0.4, 0.0, 20.0], [0.4, 0.0, 32.0]]))
    assert p.chaos_sd[1, 0] > 1.5 * p.chaos_sd[0, 0]


def test_new_runs_covered_as_often_as_claimed_over_seeds():
    """Over 6 independent designs and 400 new runs each, the 95 % interval of a new run covers
    it 90-99 % of the time and the mean z^2 is near 1 - jump included."""
    cover, z2 = [], []
    for seed in range(6):
        rng = np.random.default_rng(100 + seed)
        em, *_ = fitted(rng)
        Xt = np.column_stack([rng.uniform(0.1, 0.7, 400), rng.uniform(0, 1, 400),
                              rng.choice(list(CHAOS), 400)])
        yt = runs_at(Xt, rng)
        p = em.predict_parts(Xt)
        z = (yt - p.mean[:, 0]) / p.sd(1)[:, 0]
        cover.append(np.mean(np.abs(z) <= 1.96))
        z2.append(np.mean(z ** 2))
    assert 0.90 <= np.mean(cover) <= 0.99, cover
    assert 0.6 <= np.median(z2) <= 1.6, z2


def test_mean_response_sd_shrinks_below_one_runs_chaos():
    em, *_ = fitted(np.random.default_rng(3), jump=False)
    X = np.array([[0.3, 0.0, 26.0], [0.5, 0.5, 20.0]])
    p = em.predict_parts(X)
    assert np.all(p.sd(np.inf) < p.sd(1))
    assert np.allclose(p.sd(np.inf), p.latent_sd)
    err = np.abs(p.mean[:, 0] - truth(X[:, 0], X[:, 1], X[:, 2], False))
    assert np.all(err < 3 * p.latent_sd[:, 0] + 1e-3)


def test_effect_learned_jointly_with_the_base_parameter():
    """The effect's size at another restitution than the reference is predicted: the change
    from s=0 to s=1 at cr=0.65 is 0.15 * 0.95, at cr=0.15 only 0.15 * 0.45."""
    em, *_ = fitted(np.random.default_rng(4), jump=False)
    X = np.array([[0.15, 0.0, 26.0], [0.15, 1.0, 26.0], [0.65, 0.0, 26.0], [0.65, 1.0, 26.0]])
    m = em.predict(X)[:, 0]
    d_lo, d_hi = m[0] - m[1], m[2] - m[3]
    assert abs(d_lo - 0.15 * 0.45) < 0.025 and abs(d_hi - 0.15 * 0.95) < 0.025, (d_lo, d_hi)


def test_block_leave_out_equals_refit_without_the_block():
    """The closed-form leave-out of a whole design point equals a GP refitted without its runs
    (hyperparameters held)."""
    from sklearn.gaussian_process import GaussianProcessRegressor
    em, X, y, groups = fitted(np.random.default_rng(5), jump=False)
    ys, m, s = em.leave_out(groups)
    gp = em.gps_[0]
    Xs = em._scale(X)
    for g in (0, 7):
        b = groups == g
        sub = GaussianProcessRegressor(kernel=gp.kernel_, optimizer=None, normalize_y=False,
                                       alpha=np.asarray(gp.alpha)[~b] if np.ndim(gp.alpha)
                                       else gp.alpha)
        sub.fit(Xs[~b], gp.y_train_[~b])
        mb, sb = sub.predict(Xs[b], return_std=True)
        alpha_b = np.asarray(gp.alpha)[b] if np.ndim(gp.alpha) else gp.alpha
        scale, shift = gp._y_train_std, gp._y_train_mean
        assert np.allclose(m[b, 0], mb * scale + shift, atol=1e-6)
        assert np.allclose(s[b, 0], np.sqrt(sb ** 2 + alpha_b) * scale, rtol=1e-4)


def test_leave_out_coverage_matches_held_out_runs():
    em, X, y, groups = fitted(np.random.default_rng(6))
    rep = em.loo_report(groups=groups)
    assert 0.85 <= rep.loc["y", "coverage95"] <= 1.0
    assert 0.4 <= rep.loc["y", "mean_z2"] <= 2.0


def test_log_output_and_bad_input():
    rng = np.random.default_rng(7)
    X = rng.random((40, 2))
    y = np.exp(1.0 + X[:, 0]) * (1 + 0.01 * rng.standard_normal(40))
    em = GPEmulator({"a": (0, 1), "b": (0, 1)}, outputs=("y",), log_outputs=("y",),
                    random_state=0).fit(X, y)
    m = em.predict(np.array([[0.5, 0.5]]))[0, 0]
    assert abs(m / np.exp(1.5) - 1) < 0.02
    with pytest.raises(ValueError, match="must be > 0"):
        GPEmulator({"a": (0, 1), "b": (0, 1)}, outputs=("y",), log_outputs=("y",)).fit(X, -y)
    with pytest.raises(ValueError, match="noise key"):
        GPEmulator({"a": (0, 1), "b": (0, 1)}, outputs=("y",), noise_keys=("f",)).fit(X, y)


# --------------------------------------------------------------------------- the design

def _space():
    dem = tuple(c for c in CANDIDATES if c.kind == "dem")
    return DesignSpace.of(("restitution", "amplitude_m", "static_friction",
                           "rolling_friction"), dem)


def test_initial_design_fills_the_priors_and_turns_one_effect_on_at_a_time():
    space = _space()
    pts = initial_design(space, 24, seed=3)
    b = space.bounds()
    for n in space.names:
        assert (pts[n] >= b[n][0]).all() and (pts[n] <= b[n][1]).all()
    # Latin hypercube: each base parameter has one point in each of 24 strata
    for n in space.base_names:
        u = (pts[n] - b[n][0]) / (b[n][1] - b[n][0])
        assert sorted(np.floor(u * 24).astype(int)) == list(range(24))
    on = (pts[space.effect_names] > 0).sum(axis=1)
    assert on.max() == 1 and on.sum() == 12
    assert (pts[space.effect_names] > 0).any().all()          # every effect appears
    with pytest.raises(ValueError, match="not a movable parameter"):
        DesignSpace.of(("restitution", "youngs_modulus"))


def test_effects_config_and_theta_of_a_point():
    space = _space()
    c = space.effects[0]
    pt = {n: 0.0 for n in space.effect_names}
    pt.update({n: 0.4 for n in space.base_names})
    pt[effect_input(c.name)] = 0.5 * c.s_max
    assert space.effects_config(pt) == c.spec(0.5 * c.s_max)
    assert space.theta(pt) == {n: 0.4 for n in space.base_names}


def test_implausibility_and_maximin():
    imp = implausibility(np.array([[1.0, 2.0], [1.0, 5.0]]), np.zeros((2, 2)),
                         np.full((2, 2), 0.3), np.array([1.0, 2.0]), np.array([0.4, 0.4]))
    assert np.allclose(imp[0], 0.0) and np.isclose(imp[1, 1], 3.0 / 0.5)
    assert list(not_ruled_out(imp)) == [True, False]
    assert list(not_ruled_out(imp, which=2)) == [True, True]
    pool = np.array([[0.0, 0.0], [0.01, 0.0], [1.0, 1.0]])
    assert sorted(maximin_pick(pool, np.empty((0, 2)), 2)) == [0, 2] or \
        sorted(maximin_pick(pool, np.empty((0, 2)), 2)) == [1, 2]


def test_waves_keep_the_truth_and_shrink_the_plausible_space():
    """History matching on an analytic twin with known truth: from 4 points the emulator is
    unsure and rules little out; each wave's points go where the data's plausible region lies,
    until the emulator rules out what the exact model rules out (within 1.5x of its volume),
    never the truth, and keeps >= 95 % of what the exact model keeps."""
    space = DesignSpace.of(("restitution", "amplitude_m"))
    conds = np.array([20.0, 26.0, 32.0])
    sd_obs = 0.01

    def model(pts, f):
        return truth(pts["restitution"].to_numpy()[:, None], 0.0, f[None], jump=False) \
            * pts["amplitude_m"].to_numpy()[:, None] / 0.013

    true = pd.DataFrame({"restitution": [0.42], "amplitude_m": [0.0131]})
    rng = np.random.default_rng(8)
    obs = pd.DataFrame({"value": model(true, conds)[0] + sd_obs * rng.standard_normal(3),
                        "sd": sd_obs})
    cand = candidate_sample(space, 2048, 11)
    exact = not_ruled_out(implausibility(model(cand, conds), 0.0, 0.0, obs["value"],
                                         obs["sd"]))
    pts = initial_design(space, 4, seed=1)
    b = dict(space.bounds(), f=(19.0, 33.0))
    fracs = []
    for wave in range(4):
        X = pd.DataFrame({n: np.repeat(pts[n].to_numpy(), 3) for n in space.names})
        X["f"] = np.tile(conds, len(pts))
        y = model(pts, conds).ravel() + 0.002 * rng.standard_normal(len(X))
        em = GPEmulator(b, outputs=("y",), trend=True, random_state=0,
                        n_restarts_optimizer=0).fit(X, y)

        def predict(c):
            Xc = pd.DataFrame({n: np.repeat(c[n].to_numpy(), 3) for n in space.names})
            Xc["f"] = np.tile(conds, len(c))
            p = em.predict_parts(Xc)
            return type(p)(*(a.reshape(len(c), 3) for a in (p.mean, p.latent_sd, p.chaos_sd)))

        t = predict(true)
        assert not_ruled_out(implausibility(t.mean, t.latent_sd, t.chaos_sd,
                                            obs["value"], obs["sd"]))[0]
        new, frac = next_wave(space, predict, obs, pts, 6, seed=wave, n_candidates=2048)
        fracs.append(frac)
        new["point"] = np.arange(len(pts), len(pts) + len(new))
        pts = pd.concat([pts, new], ignore_index=True)
    pc = predict(cand)
    kept = not_ruled_out(implausibility(pc.mean, pc.latent_sd, pc.chaos_sd, obs["value"],
                                        obs["sd"]))
    assert fracs[-1] < fracs[0], fracs
    assert kept.mean() <= 1.5 * exact.mean() + 0.01, (kept.mean(), exact.mean())
    assert kept[exact].mean() >= 0.95, kept[exact].mean()
    with pytest.raises(ValueError, match="not an effect"):
        candidate_sample(space, 8, 0, effects=["powder_layer"])


def test_a_wave_refocuses_where_the_data_pin_a_parameter_sharply():
    """One observation pins the stroke to 0.1 % of its prior range: almost no uniform candidate
    survives, and the wave's points come from a cloud about the least implausible ones - all
    of them not ruled out, all near the pinned stroke."""
    from analysis.emulator import Prediction
    space = DesignSpace.of(("restitution", "amplitude_m"))

    def predict(c):
        a = c["amplitude_m"].to_numpy(float)[:, None]
        r = c["restitution"].to_numpy(float)[:, None]
        m = np.hstack([a, r])
        return Prediction(m, np.zeros_like(m), np.zeros_like(m))

    obs = pd.DataFrame({"value": [0.0131, 0.4], "sd": [2e-6, 0.05]})
    pts, frac = next_wave(space, predict, obs, pd.DataFrame(columns=space.names), 6, seed=0,
                          n_candidates=1024)
    assert frac < 0.02
    assert len(pts) == 6
    assert np.all(np.abs(pts["amplitude_m"] - 0.0131) < 3 * 2e-6)
    assert np.all(np.abs(pts["restitution"] - 0.4) < 3 * 0.05)


def test_posterior_cloud_follows_the_fit_and_stays_in_the_box():
    """A focus wave about a known Gaussian posterior: each fitted input's spread is the scaled
    standard error, the correlation is kept, the inputs not fitted sit at the centre, an effect
    not found stays off; an se wider than the box spreads over it, clipped to the bounds."""
    space = _space()
    e0, e1 = space.effect_names[0], space.effect_names[1]
    b = space.bounds()
    centre = {"restitution": 0.40, "amplitude_m": 0.0130, "static_friction": 0.5,
              "rolling_friction": 0.3, e0: 0.5 * b[e0][1]}
    names = ["restitution", "amplitude_m", e0]
    sd = np.array([0.01, 2e-5, 0.02 * b[e0][1]])
    rho = np.array([[1.0, -0.8, 0.0], [-0.8, 1.0, 0.3], [0.0, 0.3, 1.0]])
    cov = pd.DataFrame(rho * np.outer(sd, sd), index=names, columns=names)
    pts = posterior_cloud(space, centre, cov, 400, seed=1, scale=2.0)
    assert list(pts.columns) == space.names and len(pts) == 400
    for k, s_k in zip(names, sd):
        assert pts[k].std() == pytest.approx(2.0 * s_k, rel=0.1), k
        assert pts[k].mean() == pytest.approx(centre[k], abs=0.2 * s_k), k
    r = np.corrcoef(pts["restitution"], pts["amplitude_m"])[0, 1]
    assert r == pytest.approx(-0.8, abs=0.06)
    assert (pts["static_friction"] == 0.5).all() and (pts["rolling_friction"] == 0.3).all()
    assert (pts[e1] == 0.0).all()                                  # not found: off
    # a parameter the data do not pin (se far wider than its prior): over the box, clipped
    wide = pd.DataFrame([[1.0]], index=["static_friction"], columns=["static_friction"])
    w = posterior_cloud(space, centre, wide, 200, seed=2)
    lo, hi = b["static_friction"]
    assert w["static_friction"].between(lo, hi).all()
    assert w["static_friction"].std() > 0.25 * (hi - lo)
    # an se that is not finite (a parameter on its bound): 5 % of its range
    nan = pd.DataFrame([[np.nan]], index=["restitution"], columns=["restitution"])
    n = posterior_cloud(space, centre, nan, 200, seed=3)
    lo, hi = b["restitution"]
    assert n["restitution"].std() == pytest.approx(0.05 * (hi - lo), rel=0.15)
    with pytest.raises(ValueError, match="not inputs"):
        posterior_cloud(space, {"youngs_modulus": 1.0}, cov, 4, seed=0)
    assert posterior_cloud(space, centre, cov, 0, seed=0).empty


def _effect_centre():
    """The design space, its first effect input, that input's range and a fit's centre with
    the effect at 30 % of its range."""
    space = _space()
    e0 = space.effect_names[0]
    lo, hi = space.bounds()[e0]
    centre = {"restitution": 0.40, "amplitude_m": 0.0130, "static_friction": 0.5,
              "rolling_friction": 0.3, e0: 0.3 * hi}
    return space, e0, lo, hi, centre


def test_posterior_cloud_spreads_an_effect_over_its_whole_range():
    """A focus wave with an effect's strength spread: the strength stratified over its range
    (one point in each of n equal bins, far from the fit's own Gaussian), the base parameters
    still drawn from the fit's Gaussian, an unknown spread input refused."""
    space, e0, lo, hi, centre = _effect_centre()
    names = ["restitution", e0]
    sd = np.array([0.01, 0.01 * hi])
    cov = pd.DataFrame(np.diag(sd ** 2), index=names, columns=names)
    n = 8
    pts = posterior_cloud(space, centre, cov, n, seed=4, spread=[e0])
    bins = np.floor((pts[e0].to_numpy() - lo) / (hi - lo) * n).astype(int)
    assert sorted(bins) == list(range(n))             # one point in every bin of the range
    assert (pts[e0] > centre[e0] + 10 * sd[1]).sum() >= n // 2   # far beyond the fit's cloud
    big = posterior_cloud(space, centre, cov, 400, seed=5, spread=[e0])
    assert big["restitution"].std() == pytest.approx(2.0 * sd[0], rel=0.1)
    assert big["restitution"].mean() == pytest.approx(0.40, abs=0.002)
    with pytest.raises(ValueError, match="not inputs"):
        posterior_cloud(space, centre, cov, 4, seed=0, spread=["youngs_modulus"])


def test_posterior_cloud_follows_a_ridge_with_the_conditional_spread():
    """A focus wave along a ridge: with a Gaussian posterior the ridge of the base parameters
    at a held strength is the conditional mean, and the spread about it the conditional sd
    (here 0.6 of the marginal for rho = -0.8) - both known; the strength stays stratified."""
    space, e0, lo, hi, centre = _effect_centre()
    names = ["restitution", e0]
    sd = np.array([0.01, 0.2 * hi])
    rho = -0.8
    cov = pd.DataFrame(np.array([[1.0, rho], [rho, 1.0]]) * np.outer(sd, sd), index=names,
                       columns=names)

    def ridge(held):
        s = held[e0].to_numpy(float)
        return pd.DataFrame({"restitution": 0.40 + rho * sd[0] / sd[1] * (s - centre[e0])})
    pts = posterior_cloud(space, centre, cov, 400, seed=6, spread=[e0], ridge=ridge)
    resid = pts["restitution"] - ridge(pts[[e0]])["restitution"]
    assert resid.mean() == pytest.approx(0.0, abs=0.002)
    assert resid.std() == pytest.approx(2.0 * sd[0] * np.sqrt(1 - rho ** 2), rel=0.1)
    assert np.corrcoef(pts[e0], pts["restitution"])[0, 1] < -0.6    # along the ridge
    bins = np.floor((pts[e0].to_numpy() - lo) / (hi - lo) * 400).astype(int)
    assert sorted(bins) == list(range(400))


def test_mix_modes_has_the_moments_of_the_mixture():
    """mix_modes against a Monte-Carlo draw of the mixture it describes: a new run is in mode k
    with probability p_k, the mode's mean uncertain by its latent sd, plus its chaos - the
    mixture's mean and total variance match the draw's to sampling error; a block's
    cross-condition covariance is sum_k p_ik p_jk C_k(i, j); one mode with p = 1 gives that
    mode back."""
    from analysis.emulator import Prediction, mix_modes
    rng = np.random.default_rng(4)
    p = np.array([[0.3, 0.7], [0.9, 0.1]])
    m = [np.array([[50.0], [52.0]]), np.array([[70.0], [71.0]])]
    lat = [np.array([[1.0], [2.0]]), np.array([[3.0], [1.5]])]
    ch = [np.array([[0.5], [0.6]]), np.array([[0.2], [0.3]])]
    corr = [np.array([[[[1.0, 0.8], [0.8, 1.0]]]]), np.array([[[[1.0, 0.5], [0.5, 1.0]]]])]
    parts = [Prediction(m[k], lat[k], ch[k], corr[k]) for k in range(2)]
    mix = mix_modes(parts, p, block=2)
    n = 400_000
    for i in range(2):
        k = (rng.uniform(size=n) < p[i, 1]).astype(int)
        mu = np.where(k, m[1][i, 0], m[0][i, 0])
        sd = np.sqrt(np.where(k, lat[1][i, 0] ** 2 + ch[1][i, 0] ** 2,
                              lat[0][i, 0] ** 2 + ch[0][i, 0] ** 2))
        y = mu + sd * rng.standard_normal(n)
        assert mix.mean[i, 0] == pytest.approx(y.mean(), abs=4 * y.std() / np.sqrt(n))
        total = mix.latent_sd[i, 0] ** 2 + mix.chaos_sd[i, 0] ** 2
        assert total == pytest.approx(y.var(), rel=0.01)
        assert np.sum(mix.mode_dev[i, 0] ** 2) == pytest.approx(
            np.sum(p[i] * (np.array([m[0][i, 0], m[1][i, 0]]) - mix.mean[i, 0]) ** 2))
    cov01 = sum(p[0, k] * p[1, k] * corr[k][0, 0, 0, 1] * lat[k][0, 0] * lat[k][1, 0]
                for k in range(2))
    assert mix.latent_corr[0, 0, 0, 1] * mix.latent_sd[0, 0] * mix.latent_sd[1, 0] == \
        pytest.approx(cov01)
    one = mix_modes(parts[:1], np.ones((2, 1)), block=2)
    assert np.allclose(one.mean, m[0]) and np.allclose(one.latent_sd, lat[0])
    assert np.allclose(one.chaos_sd, ch[0]) and np.allclose(one.latent_corr, corr[0])


def test_block_correlations_are_the_gps_posterior_covariance():
    """predict_parts(X, block): each block's latent correlations are sklearn's own posterior
    covariance (GaussianProcessRegressor.predict(return_cov=True), normalised, its white term
    taken off the diagonal) scaled to unit diagonal - for blocks that span the kernel's
    chunks (200 blocks of 6 rows, 85 blocks a chunk)."""
    rng = np.random.default_rng(0)
    b = {"a": (0.0, 1.0), "b": (0.0, 2.0), "c": (-1.0, 1.0)}
    lo = np.array([0.0, 0.0, -1.0])
    span = np.array([1.0, 2.0, 2.0])
    X = pd.DataFrame(lo + rng.uniform(size=(60, 3)) * span, columns=list("abc"))
    y = np.sin(3 * X.a) + X.b ** 2 - X.c + 0.01 * rng.standard_normal(60)
    em = GPEmulator(b, outputs=("y",), trend=True, random_state=0).fit(
        X, pd.DataFrame({"y": y}))
    Xt = pd.DataFrame(lo + rng.uniform(size=(1200, 3)) * span, columns=list("abc"))
    p = em.predict_parts(Xt, block=6)
    gp = em.gps_[0]
    Xs = em._scale(em._raw_inputs(Xt))
    for k in (0, 84, 85, 199):
        _, C = gp.predict(Xs[6 * k:6 * k + 6], return_cov=True)
        C = C / gp._y_train_std ** 2 - np.eye(6) * gp.kernel_.k2.noise_level
        d = np.sqrt(np.diag(C))
        assert np.allclose(p.latent_corr[k, 0], C / np.outer(d, d), atol=1e-9)
        assert np.allclose(p.latent_sd[6 * k:6 * k + 6, 0], d * gp._y_train_std, rtol=1e-6)


def test_a_cached_fit_is_the_same_model_bit_for_bit(tmp_path):
    """A refit of the same runs replays the cached hyperparameters: the same predictions to the
    last digit as the optimised fit (and as a fit without the cache), no new cache file; the
    replayed numbers are the ones used (an altered entry moves the prediction); another
    training set is another entry; an unreadable entry is a miss that is written again."""
    import json
    from analysis.emulator import ModeClassifier
    from analysis.fit_cache import FitCache
    cache = FitCache(tmp_path / "fits")
    X, _ = design(np.random.default_rng(3), n_points=12, replicates=2)
    y = runs_at(X, np.random.default_rng(4))
    Xt = np.random.default_rng(5).uniform([0.1, 0, 20], [0.7, 1, 32], (40, 3))

    def fit(y, **kw):
        return GPEmulator(BOUNDS, outputs=("y",), trend=True, noise_keys=("f",), random_state=0,
                          n_restarts_optimizer=1, **kw).fit(X, y).predict(Xt, return_std=True)

    plain, first = fit(y), fit(y, fit_cache=cache)
    files = sorted(cache.folder.iterdir())
    assert len(files) == 1
    again = fit(y, fit_cache=cache)
    assert sorted(cache.folder.iterdir()) == files
    for a, b, c in zip(plain, first, again):
        assert np.array_equal(a, b) and np.array_equal(b, c)
    entry = json.loads(files[0].read_text())
    entry["theta"][1] += 1.0                     # a 2.7x longer length scale of cr
    files[0].write_text(json.dumps(entry))
    assert not np.array_equal(fit(y, fit_cache=cache)[0], plain[0])
    files[0].write_text("{not json")
    assert np.array_equal(fit(y, fit_cache=cache)[0], plain[0])
    assert json.loads(files[0].read_text())["theta"] == pytest.approx(entry["theta"][:1]
                                                                       + [entry["theta"][1] - 1]
                                                                       + entry["theta"][2:])
    fit(y + 0.01, fit_cache=cache)
    assert len(list(cache.folder.iterdir())) == 2
    for labels in (np.where(X[:, 0] > 0.4, "a", "b"),
                   np.where(X[:, 0] > 0.5, "a", np.where(X[:, 2] > 25, "b", "c"))):
        p = [ModeClassifier(BOUNDS, random_state=1, fit_cache=c).fit(X, labels).predict_proba(Xt)
             for c in (None, cache, cache)]
        assert np.array_equal(p[0], p[1]) and np.array_equal(p[1], p[2])
    assert len(list(cache.folder.iterdir())) == 4


def test_a_fit_found_only_in_the_committed_folder_is_replayed_and_never_written_there(tmp_path):
    """The loop's cache reads the committed fits after its own folder: a fit found only there
    is the same model, copied to the own folder (which so holds every fit a loop used), and
    nothing is written to the committed folder."""
    from analysis.fit_cache import FitCache
    X, _ = design(np.random.default_rng(3), n_points=10, replicates=2)
    y = runs_at(X, np.random.default_rng(4))

    def fit(cache):
        return GPEmulator(BOUNDS, outputs=("y",), trend=True, noise_keys=("f",), random_state=0,
                          n_restarts_optimizer=1, fit_cache=cache).fit(X, y).predict(X[:5])

    made = fit(FitCache(tmp_path / "committed"))
    committed = sorted((tmp_path / "committed").iterdir())
    replayed = fit(FitCache(tmp_path / "own", also=[tmp_path / "committed"]))
    assert np.array_equal(made, replayed)
    assert [p.name for p in (tmp_path / "own").iterdir()] == [p.name for p in committed]
    assert sorted((tmp_path / "committed").iterdir()) == committed


def test_a_fit_cache_that_cannot_be_written_only_loses_the_cache(tmp_path):
    """A cache folder that cannot be made (a file stands where it should be) is no error."""
    from analysis.fit_cache import FitCache
    (tmp_path / "blocked").write_text("a file, not a folder")
    X, _ = design(np.random.default_rng(3), n_points=10, replicates=2)
    y = runs_at(X, np.random.default_rng(4))
    em = GPEmulator(BOUNDS, outputs=("y",), trend=True, noise_keys=("f",), random_state=0,
                    n_restarts_optimizer=1, fit_cache=FitCache(tmp_path / "blocked" / "fits"))
    assert np.isfinite(em.fit(X, y).predict(X[:3])).all()


def test_committed_fits_are_replaced_whole_and_only_when_all_are_fits(tmp_path):
    """replace_fits swaps the folder's fit files for the new ones (no stale one left) and
    refuses, changing nothing, a folder holding anything else."""
    from analysis.atomic_dir import OutputError
    from analysis.fit_cache import replace_fits
    new, dest = tmp_path / "new", tmp_path / "dest"
    new.mkdir(), dest.mkdir()
    (new / ("a" * 32 + ".json")).write_text("{}")
    (new / "notes.txt").write_text("not a fit")
    (dest / ("b" * 32 + ".json")).write_text("{}")
    assert replace_fits(new, dest) == 1
    assert [p.name for p in dest.iterdir()] == ["a" * 32 + ".json"]
    (dest / "mine.txt").write_text("a user's file")
    with pytest.raises(OutputError, match="not emulator fits"):
        replace_fits(new, dest)
    assert sorted(p.name for p in dest.iterdir()) == ["a" * 32 + ".json", "mine.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dest", "new"]


def test_mode_probabilities_are_scikit_learns_to_the_last_digit():
    """The classifier's own Laplace prediction (one triangular solve) gives scikit-learn's
    predict_proba bit for bit, with 2 modes (one binary classifier) and 3 (one-vs-rest,
    normalised)."""
    from analysis.emulator import ModeClassifier
    X, _ = design(np.random.default_rng(3), n_points=14, replicates=2)
    Xt = np.random.default_rng(5).uniform([0.1, 0, 20], [0.7, 1, 32], (40, 3))
    for labels in (np.where(X[:, 0] > 0.4, "a", "b"),
                   np.where(X[:, 0] > 0.5, "a", np.where(X[:, 2] > 25, "b", "c"))):
        mc = ModeClassifier(BOUNDS, random_state=1).fit(X, labels)
        ref = mc.gpc_.predict_proba(mc._scale(Xt))
        ref = ref[:, [list(mc.gpc_.classes_).index(k) for k in mc.modes_]]
        got = mc.predict_proba(Xt)
        assert np.array_equal(got, ref)
        assert np.allclose(got.sum(axis=1), 1.0) and 0.0 < got.min() and got.max() < 1.0


@pytest.mark.parametrize("trend", [True, False])
@pytest.mark.parametrize("nu", [0.5, 1.5, 2.5, np.inf, 2.0])
def test_smooth_kernel_is_scikit_learns_to_the_last_digit(trend, nu):
    """The emulator's own evaluation of each GP's smooth kernel (cross both ways, gram,
    diagonal) gives kernel_.k1's values bit for bit: with and without the linear part, for every nu with a
    closed form and for one without (then scikit-learn's object does it)."""
    from analysis.emulator import SmoothKernel
    rng = np.random.default_rng(7)
    b = {"a": (0.0, 1.0), "b": (0.0, 2.0), "c": (-1.0, 1.0), "d": (0.0, 1.0)}
    X = rng.uniform(size=(50, 4)) * [1.0, 2.0, 2.0, 1.0] + [0.0, 0.0, -1.0, 0.0]
    y = np.sin(3 * X[:, 0]) + X[:, 1] ** 2 - X[:, 2] + 0.01 * rng.standard_normal(50)
    em = GPEmulator(b, outputs=("y",), nu=nu, trend=trend, random_state=0,
                    n_restarts_optimizer=0).fit(X, y)
    gp, sk = em.gps_[0], em.smooth_[0]
    assert isinstance(sk, SmoothKernel) and sk._fast == (nu != 2.0)
    Q = em._scale(rng.uniform(size=(42, 4)) * [1.0, 2.0, 2.0, 1.0] + [0.0, 0.0, -1.0, 0.0])
    assert np.array_equal(sk.cross(Q), gp.kernel_.k1(Q, gp.X_train_))
    assert np.array_equal(sk.cross(Q, train_first=True), gp.kernel_.k1(gp.X_train_, Q))
    assert np.array_equal(sk.gram(Q), gp.kernel_.k1(Q))
    assert np.array_equal(sk.diag(Q), gp.kernel_.k1.diag(Q))
