"""The twin model for diagnose (analysis.twin_model), the hidden suite and the hidden demo, on
the FAKE analytic twin (its toy effect responses, analysis.fake_twin.toy_effect_factor): the
assembly of anchor + GP difference + signatures, the kinetics, and the blind loop end to end."""

import numpy as np
import pandas as pd
import pytest

from analysis import kinetics, twin_model
from analysis.calibrate import condition_configs
from analysis.emulator import GPEmulator
from analysis.fake_twin import run_fake_twin, simulate_fake

THETA = {"restitution": 0.35, "static_friction": 0.45, "rolling_friction": 0.25,
         "amplitude_m": 0.0127}


@pytest.fixture(scope="module")
def fake(tmp_path_factory):
    return make_fake(tmp_path_factory.mktemp("tm"))


def make_fake(root):
    """A signature library and a base emulator made with the fake twin (4 replicates)."""
    summ = twin_model.build_library(root / "lib", replicates=4, workers=1,
                                    runs_dir=root / "runs", runner=run_fake_twin,
                                    theta_ref=THETA)
    library = twin_model.load_library(root / "lib")
    from analysis.measurements import load_dataset as ld
    from analysis.config import PAPER_TABLE3_DIR
    cond = ld(PAPER_TABLE3_DIR).conditions.assign(
        ball_diameter_m=lambda d: d["ball_diameter_mm"] * 1e-3)
    rng = np.random.default_rng(0)
    rows = []
    for k in range(12):
        th = {"restitution": rng.uniform(0.1, 0.7), "static_friction": rng.uniform(0.3, 0.7),
              "rolling_friction": rng.uniform(0.1, 0.5), "amplitude_m": rng.uniform(0.010, 0.016)}
        t = simulate_fake(condition_configs(th, cond, seed=k))
        rows.append(t)
    d = pd.concat(rows, ignore_index=True)
    names = ["restitution", "static_friction", "rolling_friction", "amplitude_m",
             "frequency_hz", "ball_diameter_m"]
    em = GPEmulator({k: (float(d[k].min()), float(d[k].max())) for k in names},
                    random_state=0, n_restarts_optimizer=0).fit(d[names], d[["v_mean_m_s",
                                                                              "f_col_hz"]])
    return {"root": root, "summ": summ, "library": library, "emulator": em, "conditions": cond}


def model_for(fake, times=None):
    return twin_model.TwinModel(fake["conditions"], times or {}, library=fake["library"],
                                emulator=fake["emulator"])


def test_library_has_every_dem_candidate_at_its_signature_strength(fake):
    s = fake["summ"]
    dem = [c for c in twin_model.CANDIDATES if c.kind == "dem"]
    assert set(s["label"]) == {"none"} | {c.name for c in dem}
    for c in dem:
        got = sorted(set(s.loc[s["label"] == c.name, "strength"]))
        assert got == pytest.approx([fr * c.s_max for fr in c.signature_levels])
        assert (s["label"] == c.name).sum() == 8 * len(c.signature_levels)
    assert (s["n"] == 4).all()
    assert (fake["root"] / "lib" / "signatures.png").stat().st_size > 1000
    page = (fake["root"] / "lib" / "README.md").read_text()
    assert "jar_compliance (f_n_hz = 81.6" in page and page.count("| f30_d20.6 |") == 2


def test_model_reproduces_anchor_and_signatures(fake):
    m = model_for(fake)
    s = fake["summ"].set_index(["label", "condition_id"])
    p0 = m.predict(THETA, {})
    for cid in m.conditions["condition_id"]:
        assert p0[(cid, "v_mean_m_s")] == pytest.approx(s.loc[("none", cid), "v_mean_m_s"],
                                                         rel=1e-9)
    c = twin_model.candidates()["viscoelastic_restitution"]
    s = fake["summ"].set_index(["label", "strength", "condition_id"])
    full = m.predict(THETA, {"viscoelastic_restitution": c.s_max})
    half = m.predict(THETA, {"viscoelastic_restitution": 0.5 * c.s_max})
    q = m.predict(THETA, {"viscoelastic_restitution": 0.25 * c.s_max})
    tq = m.predict(THETA, {"viscoelastic_restitution": 0.75 * c.s_max})
    for cid in m.conditions["condition_id"]:
        v_lib = s.loc[("viscoelastic_restitution", c.s_max, cid), "v_mean_m_s"]
        v_half = s.loc[("viscoelastic_restitution", 0.5 * c.s_max, cid), "v_mean_m_s"]
        v0 = p0[(cid, "v_mean_m_s")]
        assert full[(cid, "v_mean_m_s")] == pytest.approx(v_lib, rel=1e-9)
        assert half[(cid, "v_mean_m_s")] == pytest.approx(v_half, rel=1e-9)
        # piecewise linear between the levels (0, s_max / 2, s_max)
        assert q[(cid, "v_mean_m_s")] == pytest.approx(0.5 * (v0 + v_half), rel=1e-9)
        assert tq[(cid, "v_mean_m_s")] == pytest.approx(0.5 * (v_half + v_lib), rel=1e-9)


def test_base_parameters_move_the_prediction_like_the_fake_twin(fake):
    """The GP difference follows the toy: raising A by 10 % raises v by ~10 %."""
    m = model_for(fake)
    p0 = m.predict(THETA, {})
    p1 = m.predict(dict(THETA, amplitude_m=THETA["amplitude_m"] * 1.1), {})
    ratio = (p1.xs("v_mean_m_s", level=1) / p0.xs("v_mean_m_s", level=1)).to_numpy()
    assert np.all(np.abs(ratio - 1.1) < 0.03)


def test_yields_follow_the_powder_line_and_kinetics_effects(fake):
    times = {cid: [5.0, 10.0] for cid in fake["conditions"]["condition_id"]}
    m = model_for(fake, times)
    th = dict(THETA, slope_pct_per_kj=9.49, intercept_pct=-3.03)
    p = m.predict(th, {})
    cid = "f25_d20.6"
    v, f = p[(cid, "v_mean_m_s")], p[(cid, "f_col_hz")]
    e = 0.5 * kinetics.ball_mass_kg(0.0206) * v * v * f * 600.0
    assert p[(cid, "yield_pct@10min")] == pytest.approx(9.49 * e / 1000 - 3.03, rel=1e-9)
    q = m.predict(th, {"induction_period": 500.0})
    assert q[(cid, "yield_pct@10min")] == pytest.approx(9.49 * (e - 500) / 1000 - 3.03,
                                                        rel=1e-9)
    with pytest.raises(ValueError, match="do not compose"):
        m.predict(th, {"induction_period": 500.0, "first_order_depletion": 0.5})
    with pytest.raises(ValueError, match="unknown effect"):
        m.predict(th, {"no_such": 1.0})
    se = m.model_se(th)
    assert (se > 0).all() and len(se) == len(p)


#: the diagnose catalog as it was declared in twin_model before the effect files declared it
#: (name, kind, param, s_max, unit, coord, p0, levels, replicates), in order: a change here
#: changes run ids, the library and every plot - make it on purpose
EXPECTED_CANDIDATES = [
    ("viscoelastic_restitution", "dem", "k", 0.6, "-", "linear", 1.0, None, None),
    ("arc_motion", "dem", "curvature_1_m", 15.0, "1/m", "linear", 1.0, None, None),
    ("jar_compliance", "dem", "f_n_hz", 1.5, "Hz", "inv_square", 100.0,
     (0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1.0), 4),
    ("powder_layer", "dem", "layer_thickness_m", 1.0, "m", "square", 5e-4, None, None),
    ("rolling_resistance", "dem", "extra_rolling_friction", 2.0, "-", "linear", 1.0, None, None),
    ("air_drag", "dem", "drag_scale", 1.0, "-", "linear", 1.0, None, None),
    ("impact_threshold", "kinetics", "threshold_energy_j", 0.04, "J", "linear", 1.0, None, None),
    ("first_order_depletion", "kinetics", "depletion", 1.0, "-", "linear", 1.0, None, None),
    ("induction_period", "kinetics", "induction_energy_j", 1500.0, "J", "linear", 1.0, None,
     None),
    ("temperature_rise", "kinetics", "thermal_resistance_k_w", 1.0, "K/W", "linear", 1.0, None,
     None),
]
EXPECTED_OPTIONAL = [
    ("end_fillet", "dem", "extra_fillet_m", 0.006, "m", "linear", 1.0, None, None),
]


def test_catalog_built_from_the_effect_files_is_the_declared_table():
    def rows(cands):
        return [(c.name, c.kind, c.param, c.s_max, c.unit, c.coord, c.p0, c.levels,
                 c.replicates) for c in cands]
    assert rows(twin_model.CANDIDATES) == EXPECTED_CANDIDATES
    assert rows(twin_model.OPTIONAL_CANDIDATES) == EXPECTED_OPTIONAL
    for c in twin_model.CANDIDATES + twin_model.OPTIONAL_CANDIDATES:
        assert c.fixed == () and isinstance(c.s_max, float) and isinstance(c.p0, float)
    assert twin_model.DECOYS == ("air_drag",)
    assert list(twin_model.candidates()) == [r[0] for r in EXPECTED_CANDIDATES
                                             + EXPECTED_OPTIONAL]
    assert twin_model.candidates()["jar_compliance"].signature_levels == EXPECTED_CANDIDATES[2][7]
    assert twin_model.candidates()["arc_motion"].signature_levels == twin_model.SIGNATURE_LEVELS


def test_strength_coordinates_round_trip():
    for c in twin_model.CANDIDATES:
        s = 0.37 * c.s_max
        assert c.strength_of(c.param_value(s)) == pytest.approx(s, rel=1e-12)
    jc = twin_model.candidates()["jar_compliance"]
    assert jc.param_value(1.0) == pytest.approx(100.0)
    import effects
    for c in twin_model.CANDIDATES:   # the top of every range is inside the catalog's bounds
        effects.validate(c.name, c.spec(c.s_max)[c.name])


def test_library_errors(fake, tmp_path):
    with pytest.raises(FileNotFoundError, match="make signatures"):
        twin_model.load_library(tmp_path)
    other = pd.DataFrame({"condition_id": ["elsewhere"], "frequency_hz": [20.0],
                          "ball_diameter_mm": [10.0]})
    with pytest.raises(ValueError, match="no runs at condition"):
        twin_model.TwinModel(other, {}, library=fake["library"], emulator=fake["emulator"])


def blind(fake, spec, seed, name):
    from analysis.hidden import make_hidden_dataset
    from analysis.hidden_suite import score_case
    ds, truth = make_hidden_dataset(name, spec, replicates=2, seed=seed,
                                    base_config=THETA, runner=run_fake_twin, workers=1,
                                    runs_dir=fake["root"] / "runs",
                                    out_dir=fake["root"] / "ds" / name,
                                    truth_dir=fake["root"] / "truth", progress=False)
    return score_case(ds, truth, {"library": fake["library"], "emulator": fake["emulator"]})


@pytest.mark.parametrize("spec,true", [
    ({"temperature_rise": {"thermal_resistance_k_w": 0.8}}, "temperature_rise"),
    ({"induction_period": {"induction_energy_j": 1000.0}}, "induction_period"),
])
def test_blind_fake_cases_find_the_hidden_effect(fake, spec, true):
    row = blind(fake, spec, 1, "case_" + true)
    assert row["shift_sigma_max"] >= 3
    assert row["rank1"] == true and row["reported"] == true
    assert not row["decoy_significant"]
    assert row["chi2_dof_after_add"] <= 1.5 and row["chi2_dof_after_add"] < row["chi2_dof_calibrated"]


def test_blind_fake_null_says_nothing_missing(fake):
    row = blind(fake, {}, 2, "case_null")
    assert row["status"] == "nothing_missing" and row["reported"] == ""
    assert not row["decoy_significant"]


def test_suite_resumes_and_summarises(fake, tmp_path):
    from analysis import hidden_suite
    cases = [("none", {}, None, 0.0),
             ("jar_compliance@0.8", twin_model.candidates()["jar_compliance"].spec(1.2),
              "jar_compliance", 1.2)]
    kw = dict(noise_seeds=range(2), twin_seed=3, workers=1, cases=cases, runner=run_fake_twin,
              runs_dir=fake["root"] / "runs", library=fake["library"],
              emulator=fake["emulator"], progress=False)
    rows = hidden_suite.run_suite(tmp_path / "suite", **kw)
    assert len(rows) == 4
    again = hidden_suite.run_suite(tmp_path / "suite", **kw)   # nothing recomputed
    pd.testing.assert_frame_equal(rows, again)
    summ = hidden_suite.write_report(rows, tmp_path / "suite")
    assert summ["n_null_datasets"] == 2 and summ["n_effect_datasets"] == 2
    assert (tmp_path / "suite" / "README.md").read_text().count("|") > 10
    assert (tmp_path / "suite" / "confusion.png").exists()
    # the page compares with a run without jar tracks (the fake twin has none: same figures)
    rows0 = hidden_suite.run_suite(tmp_path / "suite" / "without_tracks",
                                   **dict(kw, flights=False))
    summ0 = hidden_suite.write_report(rows0, tmp_path / "suite" / "without_tracks")
    hidden_suite._append_comparison(tmp_path / "suite" / "README.md", summ, summ0,
                                    hidden_suite.per_effect(rows), hidden_suite.per_effect(rows0))
    page = (tmp_path / "suite" / "README.md").read_text()
    assert "## With and without the jar tracks" in page
    assert "| decoy significant | %d | %d |" % (summ["decoy_significant"],
                                               summ0["decoy_significant"]) in page


def test_hidden_demo_end_to_end_on_the_fake(fake, tmp_path):
    from analysis import hidden_demo
    spec = {"induction_period": {"induction_energy_j": 1000.0}}
    out = hidden_demo.run_demo(tmp_path / "demo", effect_spec=spec, workers=1,
                               runner=run_fake_twin, runs_dir=fake["root"] / "runs",
                               library=fake["library"], emulator=fake["emulator"],
                               say=lambda *a: None)
    assert out["reveal"]["found"] and out["reveal"]["hidden_effect"] == "induction_period", out["verdict"]
    stair = pd.read_csv(tmp_path / "demo" / "staircase.csv")
    assert stair["chi2_dof"].iloc[1] > 3 * stair["chi2_dof"].iloc[2]
    assert stair["stage"].iloc[-1].endswith("(twin rerun)")
    assert stair["chi2_dof"].iloc[-1] < stair["chi2_dof"].iloc[1]
    page = (tmp_path / "demo" / "report.md").read_text()
    assert "induction_period" in page and "Reveal" in page
    # the sealed truth lives outside the dataset folder
    assert not list((tmp_path / "demo" / "dataset").glob("*truth*"))


def test_secret_choice_is_never_the_decoy():
    names = {twin_model.candidates()[next(iter(hidden_demo_choice(s)[0]))].name
             for s in range(40)}
    assert not names & set(twin_model.DECOYS) and len(names) >= 5


def hidden_demo_choice(seed):
    from analysis.hidden_demo import secret_choice
    return secret_choice(seed)


def test_hidden_demo_bad_effect_leaves_the_previous_demo(tmp_path, capsys):
    from analysis import hidden_demo
    out = tmp_path / "demo"
    out.mkdir()
    (out / "report.md").write_text("previous")
    assert hidden_demo.main(["--effect", "no_such:x=1", "--out", str(out), "--no-verify"]) == 2
    assert "unknown effect" in capsys.readouterr().err
    assert (out / "report.md").read_text() == "previous"
    assert [p.name for p in tmp_path.iterdir()] == ["demo"]      # no staging folder left


# ------------------------------------------------------------------ impact observables (flights)

FL_ANCHOR = {"e_app": 0.30, "v_in_m_s": 4.0, "impact_phase_rad": 2.3, "jar_amplitude_m": 0.0127,
             "vy_rms_m_s": 0.006}


def flight_library(fake, root):
    """The fake library with made-up impact observables (the fake twin writes no trajectory):
    anchor FL_ANCHOR, every effect level moving e_app by -0.1 x (strength / s_max)^2 (a curved
    response) and jar_compliance the jar amplitude by +5 % x strength / s_max; per-run sd 0.01 on
    e_app. A design table where e_app = 0.9 restitution and the jar amplitude = the drive."""
    from analysis.flights import FLIGHT_OBSERVABLES
    summ, meta = fake["library"]
    summ = summ.copy()
    smax = {c.name: c.s_max for c in twin_model.CANDIDATES}
    for k in FLIGHT_OBSERVABLES:
        summ[k] = FL_ANCHOR[k]
        summ[k + "_sd"] = 0.0
    summ["e_app_sd"] = 0.01
    rel = np.array([r.strength / smax[r.label] if r.label != "none" else 0.0
                    for r in summ.itertuples()])
    summ["e_app"] = FL_ANCHOR["e_app"] - 0.1 * rel ** 2
    jc = (summ["label"] == "jar_compliance").to_numpy()
    summ.loc[jc, "jar_amplitude_m"] = FL_ANCHOR["jar_amplitude_m"] * (1 + 0.05 * rel[jc])
    rng = np.random.default_rng(1)
    n = 40
    d = pd.DataFrame({"restitution": rng.uniform(0.2, 0.5, n),
                      "static_friction": rng.uniform(0.3, 0.7, n),
                      "rolling_friction": rng.uniform(0.1, 0.5, n),
                      "amplitude_m": rng.uniform(0.010, 0.016, n),
                      "frequency_hz": rng.choice([22.5, 25.0, 27.5, 30.0], n),
                      "ball_diameter_m": rng.choice([0.0175, 0.0206], n),
                      "motion_mode": "end_to_end"})
    d["e_app"] = 0.9 * d["restitution"]
    d["v_in_m_s"] = 4.0
    d["impact_phase_rad"] = 2.3
    d["jar_amplitude_m"] = d["amplitude_m"]
    d["vy_rms_m_s"] = 0.006
    root.mkdir(parents=True, exist_ok=True)
    d.to_csv(root / twin_model.DESIGN_FLIGHTS_FILE, index=False)
    em = twin_model.flight_emulator(root)
    return (summ, meta), em


def test_flight_observables_in_the_model(fake, tmp_path):
    lib, fem = flight_library(fake, tmp_path / "lib")
    cond = fake["conditions"]
    cids = list(cond["condition_id"])
    m = twin_model.TwinModel(cond, {}, library=lib, emulator=fake["emulator"],
                             flight_conditions=cids[:3], flight_emulator=fem)
    p0 = m.predict(THETA, {})
    assert len(p0) == 8 * 2 + 3 * 5
    assert p0[(cids[0], "e_app")] == pytest.approx(0.30, abs=1e-9)
    assert (cids[5], "e_app") not in p0.index
    jc = twin_model.candidates()["jar_compliance"]
    ve = twin_model.candidates()["viscoelastic_restitution"]
    # the levels are exact, in between piecewise linear: at 3/4 s_max the mean of -0.025, -0.1
    for fr, want in ((0.5, 0.275), (1.0, 0.2), (0.75, 0.3 - 0.0625)):
        p = m.predict(THETA, {"viscoelastic_restitution": fr * ve.s_max})
        assert p[(cids[1], "e_app")] == pytest.approx(want, abs=1e-9)
    # jar compliance has its own, denser levels: 0.75 s_max is one of them
    p = m.predict(THETA, {"jar_compliance": 0.75 * jc.s_max})
    assert p[(cids[1], "e_app")] == pytest.approx(0.3 - 0.1 * 0.75 ** 2, abs=1e-9)
    p = m.predict(THETA, {"jar_compliance": jc.s_max})
    assert p[(cids[2], "jar_amplitude_m")] == pytest.approx(0.0127 * 1.05, rel=1e-9)
    # base parameters act through the flights GP, as a difference
    q = m.predict(dict(THETA, restitution=0.40, amplitude_m=0.0135), {})
    assert q[(cids[0], "e_app")] - 0.30 == pytest.approx(0.9 * 0.05, abs=0.004)
    assert q[(cids[0], "jar_amplitude_m")] == pytest.approx(0.0135, rel=2e-3)
    # model noise: the anchor mean's se (one run's sd, floored, / sqrt(4)); one run's sd is
    # the measured track's share (factory)
    se = m.model_se()
    assert se[(cids[0], "e_app")] == pytest.approx(0.01 / 2, rel=1e-9)
    assert se[(cids[0], "vy_rms_m_s")] == pytest.approx(
        twin_model.FLIGHT_SD_FLOORS["vy_rms_m_s"] / 2, rel=1e-9)
    assert m.flight_run_sd()[(cids[2], "e_app")] == pytest.approx(0.01, rel=1e-9)
    with pytest.raises(ValueError, match="not among the conditions"):
        twin_model.TwinModel(cond, {}, library=lib, emulator=fake["emulator"],
                             flight_conditions=["nowhere"], flight_emulator=fem)
    with pytest.raises(ValueError, match="no impact observables"):
        bare = (lib[0].drop(columns=["e_app"]), lib[1])
        twin_model.TwinModel(cond, {}, library=bare, emulator=fake["emulator"],
                             flight_conditions=cids[:1], flight_emulator=fem)


def test_factory_reads_jar_tracks_and_diagnose_runs(fake, tmp_path):
    """A dataset with a jar track: the factory adds its impact observables to the observations
    and the model predicts exactly those keys; diagnose and add run on them."""
    from analysis.diagnose import add_effect, diagnose
    from analysis.measurements import Dataset
    from tests.test_flights import impact_map_track
    lib, fem = flight_library(fake, tmp_path / "lib")
    cond = fake["conditions"][["condition_id", "frequency_hz", "ball_diameter_mm"]]
    m = twin_model.TwinModel(cond, {}, library=lib, emulator=fake["emulator"])
    mu = m.predict(THETA, {})
    summ = pd.DataFrame({"condition_id": cond["condition_id"],
                         "v_mean_m_s": mu.xs("v_mean_m_s", level=1).to_numpy(),
                         "v_mean_sd_m_s": 0.03, "f_col_hz": mu.xs("f_col_hz", level=1).to_numpy(),
                         "f_col_sd_hz": 1.0})
    tr, _ = impact_map_track(e=0.3, frequency_hz=25.0)
    ds = Dataset(name="jar", description="", source="test", velocity_frame="lab",
                 conditions=cond, summary=summ, tracks={"f25_d20.6": tr})
    prob = twin_model.factory(ds, library=lib, emulator=fake["emulator"], flight_emulator=fem)
    obs = prob["observations"]
    fl = obs[obs["condition_id"].eq("f25_d20.6") & obs["observable"].eq("e_app")]
    assert len(obs) == 16 + 5 and len(fl) == 1
    from analysis.flights import dataset_flights
    own = dataset_flights(ds).set_index("observable").loc["e_app", "sd"]
    # the larger of the operator's se and one run's scatter (0.01): both are that chaos
    assert fl["sd"].iloc[0] == pytest.approx(max(own, 0.01), rel=1e-9)
    assert set(prob["noise_observables"]) >= {"e_app", "jar_amplitude_m"}
    assert set(map(tuple, obs[["condition_id", "observable"]].to_numpy())) == \
        set(prob["predict"](THETA, {}).index)
    d = diagnose(prob["predict"], obs, prob["base_params"], prob["effects"],
                 model_se=prob["model_se"], crn_correlation=0.0,
                 noise_observables=prob["noise_observables"], conditions=cond)
    assert len(d.table) == len(prob["effects"])
    a = add_effect(prob["predict"], obs, prob["base_params"], prob["effects"], "jar_compliance",
                   model_se=prob["model_se"])
    assert np.isfinite(a.staircase["chi2_dof"]).all()
    no = twin_model.factory(ds, library=lib, emulator=fake["emulator"], flights=False)
    assert len(no["observations"]) == 16


def test_library_flags_runs_in_the_late_impact_pattern():
    """A run meeting the wall at < 60 % of the anchor's approach speed is 'late'; a level whose
    seeds differ is counted (mixed), never averaged silently."""
    rows = []
    for lab, s, vin in (("none", 0.0, [4.0, 4.1]), ("jar_compliance", 0.5, [4.0, 1.2]),
                        ("jar_compliance", 1.0, [1.1, 1.3])):
        for k, v in enumerate(vin):
            rows.append({"label": lab, "strength": s, "condition_id": "c", "seed": k,
                         "v_mean_m_s": 2.0 + 0.1 * (v < 2), "f_col_hz": 50.0, "v_in_m_s": v})
    s = twin_model.summarise_library(pd.DataFrame(rows)).set_index(["label", "strength"])
    assert s.loc[("none", 0.0), "n_late_pattern"] == 0
    assert s.loc[("jar_compliance", 0.5), "n_late_pattern"] == 1
    assert s.loc[("jar_compliance", 1.0), "n_late_pattern"] == 2


def test_signatures_follow_the_measured_impact_pattern():
    """Per-pattern library columns: a condition measured in the 'late' pattern takes only the
    late runs (flat below the first late level), a normal one only the normal runs from (0, 0);
    two motions are never averaged."""
    anchor = np.array([[2.0], [2.0]])
    d = pd.DataFrame({"label": "x", "strength": [0.5, 0.5, 1.0, 1.0],
                      "condition_id": ["a", "b", "a", "b"],
                      "v_mean_m_s": [2.1, 2.1, 2.5, 2.5],
                      "v_mean_m_s@normal": [2.1, 2.1, np.nan, 2.2],
                      "v_mean_m_s@late": [np.nan, np.nan, 2.5, 2.6]})
    sig = twin_model._levels(d, ["a", "b"], ["v_mean_m_s"], anchor, {"b": "late"})
    assert list(sig[0][0]) == [0.0, 0.5]                  # a: normal runs only
    assert list(sig[1][0]) == [1.0]                       # b: its late level only
    y = twin_model.interp_levels(sig, 0.25)
    assert y[0, 0] == pytest.approx(0.05) and y[1, 0] == pytest.approx(0.6)
    y = twin_model.interp_levels(sig, 1.0)
    assert y[0, 0] == pytest.approx(0.2) and y[1, 0] == pytest.approx(0.6)
    # without the per-pattern columns: all runs, one branch
    plain = twin_model._levels(d.drop(columns=["v_mean_m_s@normal", "v_mean_m_s@late"]),
                               ["a", "b"], ["v_mean_m_s"], anchor, {"b": "late"})
    assert list(plain[1][0]) == [0.0, 0.5, 1.0]
    assert twin_model.interp_levels(plain, 0.75)[1, 0] == pytest.approx(0.3)


def test_interpolation_error_is_exact_for_a_quadratic_response():
    """The library's resolution se (curvatures, interp_sd) is zero at the levels, equals the
    true error of linear interpolation for a quadratic response (levels 0, 0.5, 1, 1.5 of
    a s^2), grows beyond the top like linear extrapolation's error, and below a late branch's
    first level (held flat) holds the branch's slope times the distance."""
    xs = np.array([0.0, 0.5, 1.0, 1.5])
    a = np.array([0.3, -2.0])
    ds = np.outer(xs ** 2, a)
    sig = [(xs, ds)]
    curv = [twin_model.curvatures(xs, ds)]
    for s in (0.1, 0.25, 0.7, 1.2, 1.45):
        err = np.abs(twin_model.interp_levels(sig, s)[0] - s * s * a)
        assert twin_model.interp_sd(sig, curv, s)[0] == pytest.approx(err, rel=1e-9)
    for s in xs[1:]:
        assert twin_model.interp_sd(sig, curv, s)[0] == pytest.approx([0.0, 0.0], abs=1e-12)
    err = np.abs(twin_model.interp_levels(sig, 1.8)[0] - 1.8 ** 2 * a)
    assert twin_model.interp_sd(sig, curv, 1.8)[0] == pytest.approx(err, rel=1e-9)
    # a late branch (levels 1, 1.5 only, flat below 1): two points, no curvature
    late = [(xs[2:], ds[2:])]
    lc = [twin_model.curvatures(xs[2:], ds[2:])]
    slope = np.abs(ds[3] - ds[2]) / 0.5
    assert twin_model.interp_sd(late, lc, 0.6)[0] == pytest.approx(slope * 0.4)
    assert twin_model.interp_sd(late, lc, 1.2)[0] == pytest.approx([0.0, 0.0])
    # a rough response (a late branch's e_app: 0.25, -0.06, 0.155) gets a wide band between
    x3 = np.array([0.9375, 1.125, 1.3125])
    d3 = np.array([[0.25], [-0.06], [0.155]])
    sd = twin_model.interp_sd([(x3, d3)], [twin_model.curvatures(x3, d3)], 1.05)[0, 0]
    assert sd == pytest.approx(0.2625 / 0.1875 ** 2 * (1.05 - 0.9375) * (1.125 - 1.05))


def test_resolution_se_of_the_twin_model(fake):
    """TwinModel.resolution_se: zero with no effect and at a library level, positive between
    levels where the response bends, per key of predict."""
    lib = fake["library"]
    conds = pd.DataFrame(lib[1]["conditions"])
    m = twin_model.TwinModel(conds, {c: [5.0] for c in conds["condition_id"]}, library=lib,
                             emulator=fake["emulator"])
    zero = m.resolution_se({})
    assert list(zero.index) == list(m.predict(m.theta_ref, {}).index)
    assert (zero == 0).all()
    c = twin_model.candidates()["jar_compliance"]
    lv = c.signature_levels[1] * c.s_max
    assert m.resolution_se({"jar_compliance": lv}).abs().max() < 1e-12
    mid = 0.5 * (c.signature_levels[1] + c.signature_levels[2]) * c.s_max
    r = m.resolution_se({"jar_compliance": mid})
    assert (r >= 0).all() and r.max() > 0
    assert m.resolution_se({"jar_compliance": mid, "air_drag": 0.0}).equals(r)


def test_a_late_branch_allows_a_step_between_levels():
    """In a condition measured in the late impact pattern a segment's error is at least the rms
    error of linear interpolation across a step at an unknown place, |d_k+1 - d_k| sqrt(w(1-w));
    a straight (normal) branch keeps zero."""
    xs = np.array([0.0, 0.5, 1.0])
    ds = np.array([[0.0], [0.1], [0.2]])            # straight: no curvature
    curv = [twin_model.curvatures(xs, ds)] * 2
    sig = [(xs, ds)] * 2
    sd = twin_model.interp_sd(sig, curv, 0.6, rough=[False, True])
    assert sd[0, 0] == pytest.approx(0.0, abs=1e-12)
    assert sd[1, 0] == pytest.approx(0.1 * np.sqrt(0.2 * 0.8))
    # Monte Carlo: a step from 0.1 to 0.2 at a uniform place in (0.5, 1); linear error rms
    rng = np.random.default_rng(0)
    loc = rng.uniform(0.5, 1.0, 200000)
    true = np.where(0.6 >= loc, 0.2, 0.1)
    assert np.sqrt(np.mean((true - 0.12) ** 2)) == pytest.approx(sd[1, 0], rel=0.01)


def test_a_level_split_between_patterns_is_not_pooled_as_scatter(fake):
    """One motion's run-to-run scatter is pooled over the library's levels; a level whose seeds
    split between the impact patterns scatters by the jump between two motions and is left
    out (else one such level inflates a condition's sd several-fold)."""
    summ, meta = fake["library"]
    conds = pd.DataFrame(meta["conditions"])
    base = twin_model.TwinModel(conds, {}, library=(summ, meta), emulator=fake["emulator"])
    bad = summ.copy()
    i = bad.index[(bad["label"] == "jar_compliance") & (bad["condition_id"] == "f30_d20.6")][0]
    bad.loc[i, "v_sd_m_s"] = 0.2 * bad.loc[i, "v_mean_m_s"]
    bad.loc[i, "f_col_sd_hz"] = 20.0
    bad["n_late_pattern"] = 0
    bad.loc[i, "n_late_pattern"] = 1                    # 1 of its seeds in the other pattern
    m = twin_model.TwinModel(conds, {}, library=(bad, meta), emulator=fake["emulator"])
    assert m.v_rel_sd_cond == pytest.approx(base.v_rel_sd_cond)
    assert m.f_col_sd_hz == pytest.approx(base.f_col_sd_hz)
    bad.loc[i, "n_late_pattern"] = int(bad.loc[i, "n"])  # all late: one motion, pooled
    m = twin_model.TwinModel(conds, {}, library=(bad, meta), emulator=fake["emulator"])
    k = list(conds["condition_id"]).index("f30_d20.6")
    assert m.v_rel_sd_cond[k] > 2 * base.v_rel_sd_cond[k]


def test_a_twin_rerun_keeps_the_runs_in_the_measured_pattern():
    """hidden_demo.runs_in_pattern: a condition measured 'late' keeps its late runs (approach
    speed < 60 % of the anchor's), a normal one its normal runs, one with no run in its pattern
    keeps all (flagged by the caller's n_replicates, never dropped)."""
    from analysis.hidden_demo import runs_in_pattern
    cid = ["a", "a", "a", "b", "b", "c", "c"]
    v_in = [4.0, 1.2, 1.3, 4.1, 1.0, 4.0, 4.2]
    ref = {"a": 4.0, "b": 4.0, "c": 4.0}
    keep = runs_in_pattern(cid, v_in, {"a": "late", "b": "normal", "c": "late"}, ref)
    assert list(keep) == [False, True, True, True, False, True, True]
    assert runs_in_pattern(cid, v_in, {}, ref).tolist() == [True, False, False, True, False,
                                                            True, True]
