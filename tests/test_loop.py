"""The open-world loop: conditions by physics, the model built at a dataset's own conditions,
forward selection, the loop's command and its output files (FAKE twin: no YADE)."""
import json

import numpy as np
import pandas as pd
import pytest

from analysis import loop
from analysis.conditions import ConditionError, match_conditions, physics_key, physics_table
from analysis.diagnose import BaseParameter, Effect
from analysis.fake_twin import run_fake_twin
from analysis.measurements import load_dataset
from analysis.open_model import BudgetError, OpenTwinModel

THETA = {"restitution": 0.35, "static_friction": 0.47, "rolling_friction": 0.25,
         "amplitude_m": 0.0127}
NEW_CONDITIONS = pd.DataFrame({"condition_id": ["a", "b", "c", "d"],
                               "frequency_hz": [26.0, 28.0, 21.0, 31.0],
                               "ball_diameter_mm": [19.0, 17.5, 15.0, 21.5]})
WIDE_CONDITIONS = pd.DataFrame({"condition_id": ["w%d" % i for i in range(8)],
                                "frequency_hz": [20.0, 21.5, 23.0, 24.5, 26.0, 27.5, 29.0, 32.0],
                                "ball_diameter_mm": [15.0, 21.0, 16.0, 20.0, 17.0, 19.0, 18.0,
                                                     22.0]})


# --------------------------------------------------------------------------- physics, not names

def test_conditions_match_by_physics_not_ids():
    paper = pd.DataFrame({"condition_id": ["f22.5_d20.6", "f30_d17.5"],
                          "frequency_hz": [22.5, 30.0], "ball_diameter_mm": [20.6, 17.5]})
    # other ids, same physics (and CSV round-off); an id that lies about its physics
    mine = pd.DataFrame({"condition_id": ["slow_big", "f30_d17.5", "fast_small"],
                         "frequency_hz": [22.500001, 26.0, 30.0],
                         "ball_diameter_mm": [20.6, 19.0, 17.5]})
    m = match_conditions(mine, paper)
    assert m == {"slow_big": "f22.5_d20.6", "f30_d17.5": None, "fast_small": "f30_d17.5"}
    # a stated stroke must match too (an unstated one takes the default)
    mine2 = mine.assign(amplitude_mm=[12.7, np.nan, 13.5])
    assert match_conditions(mine2, paper, default_amplitude_mm=12.7) == {
        "slow_big": "f22.5_d20.6", "f30_d17.5": None, "fast_small": None}
    assert physics_key(26, 19) == "f26_d19"
    assert physics_key(22.5, 20.6, 13.1) == "f22.5_d20.6_a13.1"


def test_conditions_refused_with_a_clear_error():
    two = NEW_CONDITIONS.assign(n_balls=[1, 2, 1, 1])
    with pytest.raises(ConditionError, match="'b' has n_balls = 2"):
        physics_table(two)
    dup = NEW_CONDITIONS.assign(frequency_hz=[26.0, 26.0, 21.0, 31.0],
                                ball_diameter_mm=[19.0, 19.0, 15.0, 21.5])
    with pytest.raises(ConditionError, match="same physics"):
        physics_table(dup)


def test_library_model_matches_by_physics(tmp_path):
    """The paper-condition library model pairs a dataset's conditions with its runs by physics:
    lying ids are not given the paper conditions' predictions, renamed ones are."""
    from analysis import twin_model
    summ = pd.DataFrame({"label": ["none", "none"], "strength": [0.0, 0.0],
                         "condition_id": ["f30_d17.5", "f22.5_d20.6"], "n": [2, 2],
                         "v_mean_m_s": [2.6, 1.9], "v_sd_m_s": [0.01, 0.01],
                         "f_col_hz": [60.0, 45.0], "f_col_sd_hz": [0.5, 0.5]})
    meta = {"theta_ref": THETA, "conditions": [
        {"condition_id": "f30_d17.5", "frequency_hz": 30.0, "ball_diameter_mm": 17.5},
        {"condition_id": "f22.5_d20.6", "frequency_hz": 22.5, "ball_diameter_mm": 20.6}]}
    renamed = pd.DataFrame({"condition_id": ["x", "y"], "frequency_hz": [22.5, 30.0],
                            "ball_diameter_mm": [20.6, 17.5]})
    got = twin_model.library_at(renamed, (summ, meta)).set_index("condition_id")
    assert got.loc["x", "v_mean_m_s"] == 1.9 and got.loc["y", "v_mean_m_s"] == 2.6
    lying = pd.DataFrame({"condition_id": ["f30_d17.5"], "frequency_hz": [26.0],
                          "ball_diameter_mm": [19.0]})
    with pytest.raises(ValueError, match=r"f30_d17.5 \(19 mm ball at 26 Hz\).*analysis.loop"):
        twin_model.library_at(lying, (summ, meta))


# --------------------------------------------------------------------------- the built model

@pytest.fixture
def fake_runs(tmp_path):
    return tmp_path / "runs"


def _model(conds, runs_dir, **kw):
    kw.setdefault("effect_names", ("viscoelastic_restitution", "jar_compliance"))
    return OpenTwinModel(conds, {}, theta_ref=THETA, runner=run_fake_twin, workers=1,
                         runs_dir=runs_dir, progress=False, **kw)


def test_scout_build_is_the_first_seeds_of_the_whole_build(tmp_path):
    """The loop's scout (anchor 2 seeds, every response level 1 seed) plans only runs the whole
    build plans too: when the anchor stays, the scout costs no run."""
    from analysis.sweep import prepare_configs
    whole = _model(NEW_CONDITIONS, tmp_path).plan("all")
    scout = _model(NEW_CONDITIONS, tmp_path, replicates=loop.SCOUT_REPLICATES,
                   diff_replicates=loop.SCOUT_DIFF_REPLICATES,
                   noisy_replicates=loop.SCOUT_DIFF_REPLICATES).plan("base")
    _, ids_whole = prepare_configs(list(whole["config"]))
    _, ids_scout = prepare_configs(list(scout["config"]))
    assert set(ids_scout) < set(ids_whole)
    # 4 conditions x (2 anchor + 4 base parameters x 2 sides x 1 seed)
    assert len(set(ids_scout)) == 4 * (2 + 8)
    with pytest.raises(ValueError, match="noisy_replicates"):
        _model(NEW_CONDITIONS, tmp_path, noisy_replicates=0)


def test_open_model_builds_at_new_conditions_and_resumes(fake_runs):
    m = _model(NEW_CONDITIONS, fake_runs)
    ps = m.plan_summary()
    # 4 conditions x (3 anchor + restitution, stroke: 2 sides x 2 seeds + frictions: 2 sides
    # x 3 seeds + 2 effects x 2 levels x 2 seeds)
    assert ps == {"runs": 4 * (3 + 8 + 12 + 8), "cached": 0, "new": 124,
                  "est_wall_s": 124 * 21.0}
    with pytest.raises(BudgetError, match="124 new twin runs"):
        _model(NEW_CONDITIONS, fake_runs, budget_runs=10).fit()
    assert not fake_runs.exists() or not any(fake_runs.iterdir())   # nothing ran
    m.fit()
    assert _model(NEW_CONDITIONS, fake_runs).plan_summary()["new"] == 0   # cached: resumes
    # the restitution moves the speed as the fake twin's formula does: the model's change
    # between theta and theta + one step, averaged over the conditions, against the formula's
    # (6 seeds: the fake's 1.5 % noise leaves a 0.43 % se on that mean)
    from analysis.fake_twin import toy_observables
    m6 = _model(NEW_CONDITIONS, fake_runs, replicates=6, diff_replicates=6,
                effect_names=()).fit("base")
    f = NEW_CONDITIONS["frequency_hz"].to_numpy()
    d = NEW_CONDITIONS["ball_diameter_mm"].to_numpy() * 1e-3
    hi = dict(THETA, restitution=0.41)
    ids = list(NEW_CONDITIONS["condition_id"])
    v0 = np.array([m6.predict(THETA, {})[(c, "v_mean_m_s")] for c in ids])
    v1 = np.array([m6.predict(hi, {})[(c, "v_mean_m_s")] for c in ids])
    t0, _ = toy_observables(THETA["restitution"], THETA["static_friction"],
                            THETA["rolling_friction"], THETA["amplitude_m"], f, d)
    t1, _ = toy_observables(0.41, THETA["static_friction"], THETA["rolling_friction"],
                            THETA["amplitude_m"], f, d)
    assert np.mean(v1 / v0 - 1) == pytest.approx(np.mean(t1 / t0 - 1), abs=3 * 0.0043)
    assert np.all(np.abs(v0 / t0 - 1) < 4 * 0.015 / np.sqrt(6))
    p0 = m.predict(THETA, {})
    # jar compliance speeds the ball up in the fake twin: the built response says so
    up = m.predict(THETA, {"jar_compliance": 1.5})
    assert all(up[(c, "v_mean_m_s")] > p0[(c, "v_mean_m_s")] for c in NEW_CONDITIONS["condition_id"])
    # every base parameter is fitted (the frictions with their prior), none held; how far
    # each response stands out of the noise is measured for each
    assert set(m.base_names) == {"restitution", "amplitude_m", "rolling_friction",
                                 "static_friction"}
    assert m.held == {}
    assert set(m.response_z_) == set(m.base_names)
    assert all(np.isfinite(z) for z in m.response_z_.values())
    # the model's noise: the anchor mean's se at the anchor; away from it the measured base
    # responses add theirs
    se0 = m.model_se()
    assert np.allclose(m.model_se(dict(THETA)).to_numpy(), se0.to_numpy())
    far = m.model_se(dict(THETA, restitution=THETA["restitution"] + 0.06))
    assert np.all(far.to_numpy() >= se0.to_numpy() - 1e-15)
    assert np.any(far.to_numpy() > 1.2 * se0.to_numpy())
    # the interpolation + level noise is zero at null and positive between levels
    assert float(m.resolution_se({}).abs().max()) == 0.0
    assert float(m.resolution_se({"viscoelastic_restitution": 0.45}).max()) > 0.0


def test_stated_stroke_is_run_and_not_fitted(fake_runs):
    c = NEW_CONDITIONS.iloc[:2].assign(amplitude_mm=[13.1, np.nan])
    m = _model(c, fake_runs, effect_names=())
    plan = m.plan("base")
    cfg_a = plan[(plan["condition_id"] == "a")]["config"]
    assert all(abs(x["amplitude_m"] - 0.0131) < 1e-12 for x in cfg_a)
    assert not ((plan["condition_id"] == "a") & (plan["name"] == "amplitude_m")).any()
    assert ((plan["condition_id"] == "b") & (plan["name"] == "amplitude_m")).any()


def test_jar_frame_is_honoured(fake_runs):
    """A 'jar' dataset is predicted from the recordings' jar-frame speed (the fake twin writes
    the same number in both frames: changing it in the runs shows which column is read)."""
    m = _model(NEW_CONDITIONS.iloc[:1], fake_runs, effect_names=(), velocity_frame="jar")
    m.fit("base")
    runs = m.runs_.copy()
    runs["v_mean_jar_m_s"] = runs["v_mean_m_s"] * 0.5
    m._assemble_model(runs)
    lab = _model(NEW_CONDITIONS.iloc[:1], fake_runs, effect_names=()).fit("base")
    vj = m.predict(THETA, {})[("a", "v_mean_m_s")]
    vl = lab.predict(THETA, {})[("a", "v_mean_m_s")]
    assert vj == pytest.approx(0.5 * vl, rel=1e-9)
    with pytest.raises(ValueError, match="velocity_frame"):
        _model(NEW_CONDITIONS, fake_runs, velocity_frame="camera")


# --------------------------------------------------------------------------- forward selection

class ToyModel:
    """A deterministic model with two base parameters and three effects of known shape."""

    def __init__(self, n=10, se=0.01):
        self.f = np.linspace(20, 32, n)
        self.d = np.tile([15.0, 21.0], n // 2)
        self.ids = ["c%d" % i for i in range(n)]
        self.keys = pd.MultiIndex.from_tuples(
            [(c, o) for c in self.ids for o in ("v_mean_m_s", "f_col_hz")],
            names=["condition_id", "observable"])
        self.se = se

    def predict(self, theta, effects):
        a, b = theta["a"], theta["b"]
        e1, e2, e3 = (effects.get(k, 0.0) for k in ("E1", "E2", "decoy"))
        x = (self.f - 26) / 6
        v = a + b * x + e1 * x ** 2 + e2 * (self.d - 18) / 3 + 1e-6 * e3
        fc = 2 * self.f + 0.5 * e2 * x
        return pd.Series(np.column_stack([v, fc]).ravel(), index=self.keys)

    def model_se(self, theta=None):
        return pd.Series(self.se, index=self.keys)

    def resolution_se(self, effects):
        return pd.Series(0.0, index=self.keys)

    def base_params(self):
        return [BaseParameter("a", 2.0, 1.0, 3.0), BaseParameter("b", 0.3, -1.0, 1.0)]

    def effects(self):
        return [Effect("E1", 0.0, 1.0), Effect("E2", 0.0, 1.0), Effect("decoy", 0.0, 1.0)]


def _toy_obs(model, truth, sd, seed):
    rng = np.random.default_rng(seed)
    mu = model.predict({"a": 2.2, "b": 0.4}, truth).to_numpy()
    return pd.DataFrame({"condition_id": model.keys.get_level_values(0),
                         "observable": model.keys.get_level_values(1),
                         "value": mu + sd * rng.standard_normal(len(mu)), "sd": sd})


def test_forward_selection_finds_both_effects_and_stops():
    m = ToyModel()
    truth = {"E1": 0.3, "E2": 0.2}
    hits, cover = 0, 0
    for seed in range(5):
        obs = _toy_obs(m, truth, 0.01, seed)
        fs = loop.forward_select(m, obs, {"a": 2.0, "b": 0.3}, log=lambda s: None)
        if set(fs["added"]) == {"E1", "E2"}:
            hits += 1
        last = fs["last_fit"]
        for k, s in truth.items():
            if k in last.params:
                cover += abs(last.params[k] - s) <= 1.96 * last.stderr[k]
        assert "decoy" not in fs["added"]
        assert len(fs["diagnoses"]) == len(fs["added"]) + 1    # one more step finds nothing
    assert hits == 5
    assert cover >= 9
    # no effect hidden: nothing added
    fs = loop.forward_select(m, _toy_obs(m, {}, 0.01, 7), {"a": 2.0, "b": 0.3},
                             log=lambda s: None)
    assert fs["added"] == {}
    # with the bootstrap-calibrated threshold: the same answer, and the draws are recorded
    fs = loop.forward_select(m, _toy_obs(m, truth, 0.01, 0), {"a": 2.0, "b": 0.3},
                             log=lambda s: None, null_draws=8)
    assert set(fs["added"]) == {"E1", "E2"}
    assert len(fs["null"]) == 2 and all(b["scale"] >= 1.0 for b in fs["null"])
    assert all(len(b["null_max_delta_chi2"]) == 8 for b in fs["null"])


# --------------------------------------------------------------------------- the command

@pytest.fixture
def fake_dataset(tmp_path, monkeypatch):
    """A hidden-effect dataset from the FAKE twin at conditions the paper never ran."""
    from analysis.hidden import make_hidden_dataset
    monkeypatch.setattr("analysis.config.FAKE_RUNS_DIR", tmp_path / "fake_runs")
    ds, truth = make_hidden_dataset(
        "fk", {"jar_compliance": {"f_n_hz": 85.0}}, conditions=WIDE_CONDITIONS, replicates=1,
        seed=3, base_config={"restitution": 0.32, "static_friction": 0.55,
                             "rolling_friction": 0.35, "amplitude_m": 0.0131},
        runner=run_fake_twin, runs_dir=tmp_path / "fake_runs", out_dir=tmp_path / "ds",
        truth_dir=tmp_path / "truth", twin_v_rel_sd=0.015, twin_f_col_sd_hz=0.5,
        progress=False, v_rel_sd=0.005)
    return ds


def test_loop_command_writes_its_contract(fake_dataset, tmp_path, capsys):
    out = tmp_path / "out"
    rc = loop.main(["--dataset", str(fake_dataset), "--out", str(out), "--fake",
                    "--workers", "1", "--rerun-replicates", "2", "--null-draws", "3",
                    "--max-reanchor", "0"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "staircase: baseline" in text and "wrote" in text
    d = pd.read_csv(out / "diagnosis.csv")
    for c in ("effect", "rank", "significant", "strength", "strength_se"):
        assert c in d.columns
    assert list(d["rank"]) == list(range(1, len(d) + 1))
    # the FAKE twin's effects are smooth enough in (f, d) for the recalibration to absorb
    # them (detection is tested on the toy above and on the real twin in the suite); the
    # decoy is never significant
    assert not d.loc[d["effect"] == "air_drag", "significant"].any()
    st = pd.read_csv(out / "staircase.csv")
    assert list(st["stage"][:2]) == ["baseline", "calibrated"]
    assert st["stage"].iloc[-1] == "twin rerun"
    assert st["chi2_dof"].iloc[1] <= st["chi2_dof"].iloc[0] + 1e-9   # calibration helps
    for f in ("steps.csv", "parameters.csv", "comparison.csv", "model_runs.csv",
              "staircase.png", "ranking.png"):
        assert (out / f).is_file(), f
    info = json.loads((out / "loop.json").read_text())
    assert info["conditions"][0]["label"] == "15 mm ball at 20 Hz"
    assert (out / "report.md").read_text().startswith("# The loop on fk (SYNTHETIC)")
    # a second run is all cached and replaces only its own folder
    rc = loop.main(["--dataset", str(fake_dataset), "--out", str(out), "--fake",
                    "--workers", "1", "--rerun-replicates", "2", "--null-draws", "0",
                    "--max-reanchor", "0"])
    assert rc == 0


def test_loop_budget_and_dry_run(fake_dataset, tmp_path, capsys):
    rc = loop.main(["--dataset", str(fake_dataset), "--out", str(tmp_path / "o"), "--dry-run"])
    assert rc == 0 and not (tmp_path / "o").exists()
    assert "runs" in capsys.readouterr().out
    rc = loop.main(["--dataset", str(fake_dataset), "--out", str(tmp_path / "o2"), "--fake",
                    "--budget-runs", "0", "--workers", "1"])
    assert rc == 3 and not (tmp_path / "o2").exists()
    assert "budget" in capsys.readouterr().err


def test_committed_runs_are_reused_where_the_physics_and_parameters_match():
    """At the paper's conditions and the library's anchor, the model's anchor and effect runs
    are the signature library's very runs (same configs, same run ids): nothing to rerun. A
    renamed condition still matches (physics); another frequency does not."""
    from analysis import twin_model
    summ, meta = twin_model.load_library()
    conds = pd.DataFrame(meta["conditions"]).assign(
        condition_id=lambda d: ["mine%d" % i for i in range(len(d))])
    m = OpenTwinModel(conds, {}, theta_ref=meta["theta_ref"], base=(),
                      effect_names=("viscoelastic_restitution", "jar_compliance"))
    ps = m.plan_summary()
    assert ps["runs"] == 8 * (3 + 2 * 2 * 2) and ps["new"] == 0
    moved = conds.assign(frequency_hz=conds["frequency_hz"] + 0.37)
    m2 = OpenTwinModel(moved, {}, theta_ref=meta["theta_ref"], base=(), effect_names=())
    assert m2.plan_summary()["new"] == 8 * 3


def test_speeds_in_mm_per_s_are_refused_with_a_unit_hint(tmp_path):
    import shutil
    from analysis.config import PAPER_TABLE3_DIR
    from analysis.measurements import DatasetError
    d = tmp_path / "ds"
    shutil.copytree(PAPER_TABLE3_DIR, d)
    s = pd.read_csv(d / "summary.csv")
    s.loc[2, "v_mean_m_s"] = 2440.0
    s.to_csv(d / "summary.csv", index=False)
    with pytest.raises(DatasetError, match=r"summary.csv.*row 3.*v_mean_m_s.*mm/s"):
        load_dataset(d)


def test_films_in_a_dataset_are_tracked_cached_and_read_like_tracks(tmp_path):
    """A dataset with a film instead of a track: the loop's tracking step follows ball and jar
    (against the film's ground truth), reports its quality, caches by content, and the impact
    observables read from the film's track equal those of the true track within their se."""
    import dataclasses
    from analysis.flights import dataset_flights
    from analysis.measurements import Dataset
    from analysis.synthvideo import Camera, bounce_track, render_video
    from analysis.videos import track_dataset_videos
    b = bounce_track(25.0, 0.3, restitution=0.3, mode="periodic")
    cam = Camera()
    truth = render_video(b, tmp_path / "v" / "k.mkv", cam, seed=1)
    cond = pd.DataFrame({"condition_id": ["k"], "frequency_hz": [25.0],
                         "ball_diameter_mm": [20.6]})
    summ = pd.DataFrame({"condition_id": ["k"], "v_mean_m_s": [2.0], "v_mean_sd_m_s": [np.nan],
                         "f_col_hz": [50.0], "f_col_sd_hz": [np.nan]})
    ds = Dataset(name="film", description="d", source="s", velocity_frame="lab",
                 conditions=cond, summary=summ, video={"fps": cam.fps, "m_per_px": cam.m_per_px},
                 video_files={"k": tmp_path / "v" / "k.mkv"})
    tracks, q = track_dataset_videos(ds, tmp_path / "cache", progress=False)
    tr = tracks["k"]
    assert q["n_frames"].iat[0] == len(truth) and q["n_lost"].iat[0] == 0
    assert not q["cached"].iat[0]
    # the tracker's origin is the image corner, the truth's its centre
    err = np.hypot((tr["x_m"] - tr["x_m"].mean()) - (truth["x_m"] - truth["x_m"].mean()),
                   (tr["y_m"] - tr["y_m"].mean()) - (truth["y_m"] - truth["y_m"].mean()))
    assert float(np.sqrt(np.mean(err ** 2))) < 0.1 * cam.m_per_px      # < 0.1 px rms
    jar = tr["jar_x_m"] - tr["jar_x_m"].mean()
    jt = truth["jar_x_m"] - truth["jar_x_m"].mean()
    assert float(np.sqrt(np.mean((jar - jt) ** 2))) < 0.1 * cam.m_per_px
    _, q2 = track_dataset_videos(ds, tmp_path / "cache", progress=False)
    assert q2["cached"].iat[0]
    from_film = dataset_flights(dataclasses.replace(ds, tracks=tracks, video_files={}))
    true_tr = truth[["t_s", "x_m", "y_m", "jar_x_m"]]
    from_true = dataset_flights(dataclasses.replace(ds, tracks={"k": true_tr}, video_files={}))
    a = from_film.set_index("observable")
    t = from_true.set_index("observable")
    for k in ("e_app", "v_in_m_s", "jar_amplitude_m"):
        assert abs(a.loc[k, "value"] - t.loc[k, "value"]) <= 2 * t.loc[k, "sd"], k
    assert a.loc["e_app", "value"] == pytest.approx(0.3, abs=0.02)


def test_friction_prior_enters_as_pseudo_observations(fake_runs):
    """The frictions carry the calibration's posterior as a Gaussian prior (pseudo-observations
    under condition 'prior'): predict returns the parameter there, model_se 0."""
    m = _model(NEW_CONDITIONS.iloc[:2], fake_runs, effect_names=(),
               priors={"static_friction": (0.5, 0.1), "rolling_friction": (0.3, 0.1)}).fit("base")
    names = m.prior_names
    assert set(names) <= {"static_friction", "rolling_friction"}
    pri = m.prior_observations()
    assert list(pri["observable"]) == names and set(pri["condition_id"]) <= {"prior"}
    th = dict(THETA, static_friction=0.61, rolling_friction=0.2)
    p = m.predict(th, {})
    for k in names:
        assert p[("prior", k)] == th[k]
        assert m.model_se()[("prior", k)] == 0.0
    none = _model(NEW_CONDITIONS.iloc[:2], fake_runs, effect_names=(), priors=None).fit("base")
    assert none.prior_names == [] and "prior" not in set(none.predict(THETA, {}).index
                                                        .get_level_values(0))


def test_loop_reanchors_where_the_answer_lies_beyond_the_model(tmp_path):
    """Data made far from the anchor (stroke 15.1 mm against 12.7 mm: 4 response steps): the
    loop rebuilds its model there, its final stroke lies within the new responses and near the
    truth. (The stroke alone is fitted: in the fake twin the speeds and collision rates cannot
    tell restitution, stroke and rolling friction apart far from the anchor.)"""
    from analysis.hidden import make_hidden_dataset
    from analysis.open_model import BASE_STEPS
    truth = THETA["amplitude_m"] + 4 * BASE_STEPS["amplitude_m"]
    ds_dir, _ = make_hidden_dataset(
        "far", {}, conditions=WIDE_CONDITIONS, replicates=1, seed=5,
        base_config=dict(THETA, amplitude_m=truth), runner=run_fake_twin,
        runs_dir=tmp_path / "runs", out_dir=tmp_path / "ds", truth_dir=tmp_path / "truth",
        twin_v_rel_sd=0.015, twin_f_col_sd_hz=0.5, progress=False, yield_times_min=())
    res = loop.run_loop(load_dataset(ds_dir), theta_ref=THETA, runner=run_fake_twin,
                        runs_dir=tmp_path / "runs", workers=1, progress=False, rerun=False,
                        null_draws=0, log=lambda s: None, base=("amplitude_m",))
    re = res.info["reanchors"]
    assert len(re) >= 1
    assert re[0]["to"]["amplitude_m"] > re[0]["from"]["amplitude_m"]
    # the calibrated point moved the anchor before any effect response was built: the effect
    # runs exist at the anchors of whole-model builds only (one plus one per 'all' re-anchoring)
    assert re[0]["stage"] == "base"
    strokes = set()
    for meta in (tmp_path / "runs").glob("*/meta.json"):
        cfg = json.loads(meta.read_text())["config"]
        if cfg.get("effects"):
            strokes.add(cfg["amplitude_m"])
    assert len(strokes) == 1 + sum(r["stage"] == "all" for r in re)
    par = res.parameters.set_index("name")
    fit, se = float(par.loc["amplitude_m", "value"]), float(par.loc["amplitude_m", "se"])
    anchor = res.info["anchor"]["amplitude_m"]
    assert abs(fit - anchor) <= 1.5 * BASE_STEPS["amplitude_m"]
    assert abs(fit - truth) <= 3 * se + 1e-4


def _interacting_twin(m, strength=2.5):
    """A 'twin' of the toy model whose E1 response grows with the base parameter a:
    (1 + strength (a - 2)) times the model's, the model's own at its anchor a = 2."""
    x2 = ((m.f - 26) / 6) ** 2

    def twin(theta, eff):
        y = m.predict(theta, eff).to_numpy().reshape(-1, 2).copy()
        y[:, 0] += strength * eff.get("E1", 0.0) * x2 * (theta["a"] - 2.0)
        return pd.Series(y.ravel(), index=m.keys)
    return twin


def test_twin_corrected_refits_remove_the_models_interaction_bias():
    """The 'twin' has an interaction the model lacks (E1's response 1.5 times stronger at the
    data's a = 2.2 than at the model's anchor a = 2.0): the model's own fit puts E1 many
    standard errors from the truth; refits on the model shifted onto reruns at the fitted
    point bring it within its interval, and a rerun at the truth-consistent point moves
    nothing (the refits stop)."""
    m = ToyModel(se=0.002)
    twin = _interacting_twin(m)

    truth = {"a": 2.2, "b": 0.4}
    rng = np.random.default_rng(11)
    mu = twin(truth, {"E1": 0.3}).to_numpy()
    obs = pd.DataFrame({"condition_id": m.keys.get_level_values(0),
                        "observable": m.keys.get_level_values(1),
                        "value": mu + 0.01 * rng.standard_normal(len(mu)), "sd": 0.01})
    fs = loop.forward_select(m, obs, {"a": 2.0, "b": 0.3}, log=lambda s: None)
    assert list(fs["added"]) == ["E1"]
    f0 = fs["last_fit"]
    assert abs(f0.params["E1"] - 0.3) > 3 * f0.stderr["E1"]        # the model alone: biased
    calls = []

    def rerun_fn(theta, added):
        calls.append(dict(added))
        return twin(theta, added), pd.Series(0.002, index=m.keys), pd.DataFrame({"n": [1]})

    tc = loop.twin_corrected_refits(m, obs, fs["theta"], fs["added"], f0, rerun_fn,
                                    max_refits=4, log=lambda s: None)
    fin = tc["final"]
    assert abs(fin.params["E1"] - 0.3) <= 2 * fin.stderr["E1"]
    assert abs(fin.params["a"] - 2.2) <= 2 * fin.stderr["a"]
    assert len(tc["refits"]) < 4 and tc["refits"][-1]["moved_se"] < loop.POLISH_TOL_SE
    assert len(calls) == len(tc["refits"])              # converged: no rerun after the last
    assert [s["stage"] for s in tc["stairs"]][-1] == "twin rerun"
    assert tc["stairs"][0]["stage"] == "twin-corrected"
    assert len(tc["rerun"]["runs"]) == len(calls)


def _off_anchor_twin(m):
    """A 'twin' that differs from the toy model away from its anchor (a = 2) in a way that
    looks like E1: a curvature in frequency growing with a."""
    x2 = ((m.f - 26) / 6) ** 2

    def twin(theta, eff):
        y = m.predict(theta, eff).to_numpy().reshape(-1, 2).copy()
        y[:, 0] += 1.0 * x2 * (theta["a"] - 2.0)
        return pd.Series(y.ravel(), index=m.keys)
    return twin


def _calibrated_and_corrected(m, obs, twin, max_refits):
    """The toy model calibrated on ``obs`` and its twin-corrected refits without effects
    against ``twin``: (calibrated theta, calibrated fit, refits dict)."""
    from analysis.diagnose import calibrate_base
    _, cal = calibrate_base(m.predict, obs, m.base_params(), model_se=m.model_se())
    theta = {k: float(cal.params[k]) for k in ("a", "b")}
    tc = loop.twin_corrected_refits(
        m, obs, theta, {}, cal,
        lambda th, eff: (twin(th, eff), pd.Series(0.002, index=m.keys), pd.DataFrame()),
        max_refits=max_refits, log=lambda s: None)
    return theta, cal, tc


def test_diagnosis_on_the_twin_corrected_model_drops_a_false_alarm():
    """No effect hidden, but the 'twin' differs from the model away from its anchor in a way
    that looks like E1 (a curvature in frequency growing with a): the model alone names E1;
    the same diagnosis on the model shifted onto a rerun at the calibrated point (what the
    loop does before it diagnoses) names nothing, and its calibrated a is the truth."""
    m = ToyModel(se=0.002)
    twin = _off_anchor_twin(m)

    rng = np.random.default_rng(5)
    mu = twin({"a": 2.2, "b": 0.4}, {}).to_numpy()
    obs = pd.DataFrame({"condition_id": m.keys.get_level_values(0),
                        "observable": m.keys.get_level_values(1),
                        "value": mu + 0.01 * rng.standard_normal(len(mu)), "sd": 0.01})
    raw = loop.forward_select(m, obs, {"a": 2.0, "b": 0.3}, log=lambda s: None)
    assert "E1" in raw["added"]                                   # the model alone: false alarm
    theta, cal, tc = _calibrated_and_corrected(m, obs, twin, 3)
    assert tc["corrected"] is not None
    fin = tc["final"]
    assert abs(fin.params["a"] - 2.2) <= 3 * fin.stderr["a"]
    shifted = loop._ShiftedModel(m, tc["corrected"])
    fs = loop.forward_select(shifted, obs, {k: float(fin.params[k]) for k in ("a", "b")},
                             log=lambda s: None)
    assert fs["added"] == {}


def test_unconverged_refits_state_an_se_as_large_as_their_last_step():
    """Stopped after one refit while still moving (max_refits=1), the reported se of the
    strength is at least the refit's step, and the truth lies within 2 of them."""
    m = ToyModel(se=0.002)
    twin = _interacting_twin(m)

    mu = twin({"a": 2.2, "b": 0.4}, {"E1": 0.3}).to_numpy()
    obs = pd.DataFrame({"condition_id": m.keys.get_level_values(0),
                        "observable": m.keys.get_level_values(1), "value": mu, "sd": 0.01})
    fs = loop.forward_select(m, obs, {"a": 2.0, "b": 0.3}, log=lambda s: None)
    before = fs["added"]["E1"]
    tc = loop.twin_corrected_refits(
        m, obs, fs["theta"], fs["added"], fs["last_fit"],
        lambda th, eff: (twin(th, eff), pd.Series(0.002, index=m.keys), pd.DataFrame()),
        max_refits=1, log=lambda s: None)
    step = abs(tc["added"]["E1"] - before)
    assert tc["refits"][-1]["moved_se"] > loop.POLISH_TOL_SE          # not converged
    se = tc["final"].stderr["E1"]
    assert se >= step - 1e-12
    assert abs(tc["added"]["E1"] - 0.3) <= 2 * se


def test_run_settings_fix_the_rig_and_refuse_what_the_loop_owns():
    s = loop.run_settings([("jar_inner_diameter_m", 0.03), ("rolling_model", "constant_torque")],
                          frame="jar", record_s=0.3)
    assert s == {"jar_inner_diameter_m": 0.03, "rolling_model": "constant_torque",
                 "frame": "jar", "record_s": 0.3}
    assert loop.run_settings([]) is None
    for pairs, msg in [([("restitution", 0.3)], "sets this itself"),
                       ([("frequency_hz", 25.0)], "sets this itself"),
                       ([("bogus_m", 1.0)], "not a run-config key"),
                       ([("jar_inner_length_m", 0.05)], "needs jar_inner_diameter_m"),
                       ([("rolling_model", "cdt")], "rolling_model"),
                       ([("dt_s", 1e-6), ("dt_s", 2e-6)], "twice")]:
        with pytest.raises(ValueError, match=msg):
            loop.run_settings(pairs)


def test_loop_set_reaches_every_run_and_bad_set_is_exit_2(fake_dataset, tmp_path, capsys):
    out = tmp_path / "o"
    assert loop.main(["--dataset", str(fake_dataset), "--out", str(out), "--fake",
                      "--set", "amplitude_m=0.013"]) == 2
    assert "sets this itself" in capsys.readouterr().err and not out.exists()
    rc = loop.main(["--dataset", str(fake_dataset), "--out", str(out), "--dry-run",
                    "--set", "jar_inner_diameter_m=0.03"])
    assert rc == 0
    from analysis.open_model import OpenTwinModel
    from analysis.measurements import load_dataset
    ds = load_dataset(fake_dataset)
    m = OpenTwinModel(ds.conditions, {}, velocity_frame=ds.velocity_frame,
                      base_config={"jar_inner_diameter_m": 0.03})
    assert all(c.get("jar_inner_diameter_m") == 0.03 for c in m.plan("all")["config"])


@pytest.mark.parametrize("hidden, confirmed", [(0.0, False), (0.3, True)])
def test_twin_confirms_a_real_effect_and_not_the_models_false_alarm(hidden, confirmed):
    """The model alone adds E1 in both cases (no effect hidden: its off-anchor error looks
    like E1). On the model shifted onto the 'twin''s reruns, E1 gains what the diagnosis asked
    for only where the twin holds it (E1 = 0.3 hidden)."""
    from analysis.diagnose import calibrate_base
    m = ToyModel(se=0.002)
    twin = _off_anchor_twin(m)

    def rerun(th, eff):
        return twin(th, eff), pd.Series(0.002, index=m.keys), pd.DataFrame()

    rng = np.random.default_rng(5)
    mu = twin({"a": 2.2, "b": 0.4}, {"E1": hidden}).to_numpy()
    obs = pd.DataFrame({"condition_id": m.keys.get_level_values(0),
                        "observable": m.keys.get_level_values(1),
                        "value": mu + 0.01 * rng.standard_normal(len(mu)), "sd": 0.01})
    raw = loop.forward_select(m, obs, {"a": 2.0, "b": 0.3}, log=lambda s: None)
    assert "E1" in raw["added"]
    _, cal = calibrate_base(m.predict, obs, m.base_params(), model_se=m.model_se())
    theta = {k: float(cal.params[k]) for k in ("a", "b")}
    without = loop.twin_corrected_refits(m, obs, theta, {}, cal, rerun, max_refits=3,
                                         log=lambda s: None)["final"]
    with_e = loop.twin_corrected_refits(m, obs, raw["theta"], raw["added"], raw["last_fit"],
                                        rerun, max_refits=3, log=lambda s: None)["final"]
    c = loop.twin_confirmation(without, with_e, raw["diagnoses"], raw["added"], raw["null"])
    assert c["confirmed"] is confirmed, c
    assert c["needed_chi2"] == pytest.approx(raw["diagnoses"][0].threshold_delta_chi2)
    assert loop.twin_confirmation(None, with_e, raw["diagnoses"], raw["added"]) is None


def test_assumed_v_sd_fills_only_empty_cells_and_bad_values_are_exit_2(fake_dataset, tmp_path,
                                                                        capsys):
    from analysis.measurements import load_dataset
    ds = load_dataset(fake_dataset)
    summ = ds.summary.copy()
    summ["v_mean_sd_m_s"] = np.nan                    # a dataset that states no sd ...
    summ.loc[summ.index[0], "v_mean_sd_m_s"] = 0.123  # ... but for one condition
    import dataclasses
    ds = dataclasses.replace(ds, summary=summ)
    out = loop.with_assumed_v_sd(ds, 0.01).summary
    assert out["v_mean_sd_m_s"].iloc[0] == 0.123
    rest = out.iloc[1:]
    assert np.allclose(rest["v_mean_sd_m_s"], 0.01 * rest["v_mean_m_s"].astype(float))
    for bad in (0.0, 0.7, float("nan")):
        with pytest.raises(ValueError, match="v-rel-sd"):
            loop.with_assumed_v_sd(ds, bad)
    assert loop.main(["--dataset", str(fake_dataset), "--out", str(tmp_path / "o"), "--fake",
                      "--v-rel-sd", "-1"]) == 2
    assert "v-rel-sd" in capsys.readouterr().err and not (tmp_path / "o").exists()


def test_optional_apparatus_effect_joins_the_catalog_only_when_asked(fake_dataset, tmp_path,
                                                                     capsys):
    from analysis.measurements import load_dataset
    from analysis.open_model import OpenTwinModel
    assert loop.optional_effects(["end_fillet"]) == ["end_fillet"]
    with pytest.raises(ValueError, match="not an optional"):
        loop.optional_effects(["arc_motion"])
    with pytest.raises(ValueError, match="no known fillet"):
        loop.optional_effects(["end_fillet"], {"stl_path": "my_jar.stl"})
    ds = load_dataset(fake_dataset)
    default = OpenTwinModel(ds.conditions, {}, velocity_frame=ds.velocity_frame)
    assert "end_fillet" not in default.effect_names
    plan = OpenTwinModel(ds.conditions, {}, velocity_frame=ds.velocity_frame,
                         effect_names=list(default.effect_names) + ["end_fillet"]).plan("all")
    fil = plan[plan["name"] == "end_fillet"]
    assert len(fil) > 0
    assert all(c["effects"]["end_fillet"]["extra_fillet_m"] > 0 for c in fil["config"])
    assert loop.main(["--dataset", str(fake_dataset), "--out", str(tmp_path / "o"),
                      "--dry-run", "--with-effect", "end_fillet"]) == 0
    assert loop.main(["--dataset", str(fake_dataset), "--out", str(tmp_path / "o"),
                      "--with-effect", "bogus"]) == 2
    assert "bogus" in capsys.readouterr().err


def test_shifted_model_carries_the_rerun_means_noise_not_the_extrapolation():
    """Diagnosis on the model shifted onto twin reruns: its noise is a rerun mean's (the
    anchor mean's se for the rerun's seeds), whatever the base point - not the model's own
    noise away from its anchor, which grows with the distance."""
    idx = pd.MultiIndex.from_tuples([("a", "v_mean_m_s"), ("prior", "static_friction")])

    class Stub:
        replicates = 3

        def model_se(self, theta=None):
            far = 0.0 if theta is None else abs(theta["restitution"] - 0.35) / 0.06
            return pd.Series([0.01 * (1 + 3 * far), 0.0], index=idx)

    m = loop._ShiftedModel(Stub(), corrected=None, rerun_replicates=3)
    for r in (0.35, 0.25, 0.45):
        assert list(m.model_se({"restitution": r})) == [0.01, 0.0]
    w = loop.WithAdded(m, {}, {"restitution": 0.25})
    assert list(w.model_se()) == [0.01, 0.0]
    m12 = loop._ShiftedModel(Stub(), corrected=None, rerun_replicates=12)
    assert m12.model_se()[("a", "v_mean_m_s")] == pytest.approx(0.005)


def test_final_refits_start_from_the_models_own_joint_fit():
    """With the diagnosis on a corrected model, the final refits start from the joint fit on
    the model itself from its calibrated point (not from the corrected model's, which was
    refitted without the effect): refit_start returns that fit, and nothing where no effect
    was added or the diagnosis ran on the model."""
    m = ToyModel(se=0.002)
    twin = _off_anchor_twin(m)
    mu = twin({"a": 2.2, "b": 0.4}, {"E1": 0.3}).to_numpy()
    obs = pd.DataFrame({"condition_id": m.keys.get_level_values(0),
                        "observable": m.keys.get_level_values(1), "value": mu, "sd": 0.01})
    theta, cal, tc = _calibrated_and_corrected(m, obs, twin, 1)
    shifted = loop._ShiftedModel(m, tc["corrected"])
    added = {"E1": 0.2}
    st = loop.refit_start(m, shifted, obs, theta, added)
    ref = loop.joint_fit(m, obs, theta, added)
    for k in ("a", "b", "E1"):
        assert st.params[k] == pytest.approx(ref.params[k], rel=1e-9, abs=1e-12)
    on_shifted = loop.joint_fit(shifted, obs, {k: float(tc["final"].params[k]) for k in theta},
                                added)
    assert abs(on_shifted.params["E1"] - st.params["E1"]) > 1e-6     # a different start
    assert loop.refit_start(m, shifted, obs, theta, {}) is None
    assert loop.refit_start(m, m, obs, theta, added) is None
