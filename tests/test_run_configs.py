"""The one builder of run configs at a dataset's conditions (analysis.run_configs): hand-written
expected configs, its arithmetic (run ids hash the floats), and the call sites that use it giving
one run id for one physics."""
import numpy as np
import pandas as pd
import pytest

from analysis import demo, run_configs
from analysis.config import twin_config
from analysis.sweep import prepare_configs

THETA = {"restitution": 0.35, "static_friction": 0.45, "rolling_friction": 0.25,
         "amplitude_m": 0.0127}
C1 = {"condition_id": "c1", "frequency_hz": 26.0, "ball_diameter_mm": 19.0}


def ids(configs):
    return prepare_configs(configs)[1]


def test_condition_without_a_stated_stroke():
    cfg = run_configs.condition_config(C1, THETA, seed=3,
                                       base_config={"record_s": 0.3, "restitution": 0.9})
    assert cfg == {"record_s": 0.3, "restitution": 0.35, "static_friction": 0.45,
                   "rolling_friction": 0.25, "amplitude_m": 0.0127, "frequency_hz": 26.0,
                   "ball_diameter_m": 0.019, "seed": 3}
    # a NaN or None stroke is no stroke; no effects key without effects
    for a in (np.nan, None):
        assert run_configs.condition_config(dict(C1, amplitude_mm=a), THETA, 3,
                                            {"record_s": 0.3, "restitution": 0.9}) == cfg


def test_condition_with_a_stated_stroke():
    c = dict(C1, amplitude_mm=13.1)
    assert run_configs.condition_config(c, THETA, seed=0) == {
        "restitution": 0.35, "static_friction": 0.45, "rolling_friction": 0.25,
        "amplitude_m": 0.0131, "frequency_hz": 26.0, "ball_diameter_m": 0.019, "seed": 0}
    # stated_stroke=False: theta's stroke whatever the condition states
    assert run_configs.condition_config(c, THETA, seed=0, stated_stroke=False)[
        "amplitude_m"] == 0.0127
    # the stated stroke wins over base_config's too
    assert run_configs.condition_config(c, None, 0, {"amplitude_m": 0.012})["amplitude_m"] \
        == 0.0131


def test_condition_with_effects():
    fx = {"air_drag": {}}
    cfg = run_configs.condition_config(C1, THETA, seed=1, effects=fx)
    assert cfg == {"restitution": 0.35, "static_friction": 0.45, "rolling_friction": 0.25,
                   "amplitude_m": 0.0127, "frequency_hz": 26.0, "ball_diameter_m": 0.019,
                   "seed": 1, "effects": {"air_drag": {}}}
    # effects given win over base_config's; none given (or empty) leave base_config's
    base = {"effects": {"arc_motion": {"curvature_1_m": 9.0}}}
    assert run_configs.condition_config(C1, None, 1, base, fx)["effects"] == fx
    for none in (None, {}):
        assert run_configs.condition_config(C1, None, 1, base, none)["effects"] == \
            base["effects"]


def test_arithmetic_of_the_diameter_and_of_theta():
    c = {"frequency_hz": 21, "ball_diameter_mm": 18.0, "ball_diameter_m": 18.0 / 1000.0}
    # mm: float(mm) * 1e-3; metres: the table's value as it stands. They differ in the last
    # bit at 18 mm, so they are two run ids: each caller keeps its own
    assert run_configs.condition_config(c)["ball_diameter_m"] == 0.018000000000000002
    assert run_configs.condition_config(c, diameter_column="ball_diameter_m")[
        "ball_diameter_m"] == 0.018
    cfg = run_configs.condition_config(c, {"restitution": np.float32(0.5),
                                           "rolling_model": "constant_torque"}, np.int64(4))
    assert type(cfg["frequency_hz"]) is float and type(cfg["seed"]) is int
    assert type(cfg["restitution"]) is float and cfg["rolling_model"] == "constant_torque"
    with pytest.raises(ValueError, match="diameter_column"):
        run_configs.condition_config(c, diameter_column="ball_diameter_cm")


def test_grid_over_conditions_and_seeds():
    cond = pd.DataFrame([C1, {"condition_id": "c2", "frequency_hz": 28.0,
                              "ball_diameter_mm": 17.5, "amplitude_mm": 13.5}])
    runs = run_configs.condition_runs(cond, [5, 6], THETA, {"record_s": 0.3})
    assert [(r.condition_id, r.seed) for r in runs] == [("c1", 5), ("c1", 6), ("c2", 5),
                                                        ("c2", 6)]
    assert [r.config["amplitude_m"] for r in runs] == [0.0127, 0.0127, 0.0135, 0.0135]
    # a row of a table by any route gives the same config
    by_tuple = [run_configs.condition_config(c, THETA, 5, {"record_s": 0.3})
                for c in cond.itertuples()]
    by_series = [run_configs.condition_config(c, THETA, 5, {"record_s": 0.3})
                 for _, c in cond.iterrows()]
    assert by_tuple == by_series == [runs[0].config, runs[2].config]
    assert run_configs.condition_configs(cond, [5, 6], THETA, {"record_s": 0.3}) == \
        [r.config for r in runs]
    with pytest.raises(TypeError, match="iterable of seeds"):
        run_configs.condition_runs(cond, 2)


def test_call_sites_give_one_run_id_for_one_physics():
    """The loop's run configs (the calibration's too) and the demo at the same physics (a paper
    condition, the same parameters, seed and record time) ask for the same run."""
    cond = pd.DataFrame([{"condition_id": "f30_d17.5", "frequency_hz": 30.0,
                          "ball_diameter_mm": 17.5},
                         {"condition_id": "f25_d20.6", "frequency_hz": 25.0,
                          "ball_diameter_mm": 20.6}])
    base = {"record_s": 0.3}
    om = [run_configs.condition_config(ph, THETA, 0, base)
          for ph in cond.to_dict("records")]
    dm = demo.demo_configs(cond, 1, 0.3, THETA)
    assert ids(om) == ids(dm)
    assert len(set(ids(om))) == 2
    # a condition with a stated stroke is the run at that stroke
    om_a = run_configs.condition_config(dict(cond.iloc[0], amplitude_mm=13.1), THETA, 0, base)
    at_a = run_configs.condition_configs(cond.iloc[:1], [0], dict(THETA, amplitude_m=0.0131),
                                         base, stated_stroke=False)[0]
    assert twin_config.run_id(om_a) == twin_config.run_id(at_a) != ids(om)[0]


def test_hidden_dataset_runs_a_stated_stroke_as_the_loop_models_it(tmp_path):
    """A blind dataset whose conditions state their stroke is made at that stroke: the same
    run ids as the open model's anchor at those conditions."""
    import json
    from analysis.fake_twin import run_fake_twin
    from analysis.hidden import make_hidden_dataset
    conds = pd.DataFrame({"condition_id": ["a", "b"], "frequency_hz": [26.0, 28.0],
                          "ball_diameter_mm": [19.0, 17.5], "amplitude_mm": [13.1, np.nan]})
    make_hidden_dataset("stroke", {}, conditions=conds, replicates=1, seed=0,
                        base_config=dict(THETA), runner=run_fake_twin,
                        runs_dir=tmp_path / "runs", out_dir=tmp_path / "ds",
                        truth_dir=tmp_path / "truth", progress=False, yield_times_min=())
    amps = sorted(json.loads(m.read_text())["config"]["amplitude_m"]
                  for m in (tmp_path / "runs").glob("*/meta.json"))
    assert amps == [THETA["amplitude_m"], 0.0131]


def test_frame_equivalence_builds_its_lab_runs_at_the_reference_point():
    """The jar/lab frame study runs Table 3's 8 conditions at the reference parameters in the
    lab frame (its jar runs are the same configs with frame 'jar'), seeds 0 .. n-1."""
    from analysis.parameter_space import reference_parameters
    from analysis.studies.frame_equivalence import lab_configs
    table, cfgs = lab_configs(2)
    assert len(cfgs) == len(table) == 16
    assert list(table["seed"][:2]) == [0, 1] and table["condition_id"].nunique() == 8
    ref = reference_parameters()
    for c in cfgs:
        assert c["frame"] == "lab"
        assert all(c[k] == ref[k] for k in ("restitution", "static_friction",
                                            "rolling_friction", "amplitude_m"))
