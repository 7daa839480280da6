"""Hidden-effect datasets: a measurement dataset from the twin with effects on, truth kept apart."""
import json

import numpy as np
import pytest

from analysis.config import twin_config
from analysis.fake_twin import run_fake_twin
from analysis.hidden import make_hidden_dataset, main, parse_effect
from analysis.measurements import load_dataset


def make(tmp_path, **kw):
    args = dict(replicates=2, seed=3, runner=run_fake_twin, workers=1,
                runs_dir=tmp_path / "runs", out_dir=tmp_path / "ds", truth_dir=tmp_path / "truth")
    args.update(kw)
    return make_hidden_dataset("h", {"air_drag": {}}, **args)


def test_dataset_reads_back_and_truth_is_apart(tmp_path):
    ds_path, truth_path = make(tmp_path)
    ds = load_dataset(ds_path)
    assert ds.velocity_frame == "lab" and "SYNTHETIC" in ds.description
    assert len(ds.summary) == 8 and not ds.missing_sd
    assert not (ds_path / truth_path.name).exists() and truth_path.parent != ds_path
    truth = json.loads(truth_path.read_text())
    assert truth["effects"] == {"air_drag": {}}
    assert len(truth["run_ids"]) == 16


def test_without_noise_the_dataset_is_the_twins_replicate_mean(tmp_path):
    ds_path, truth_path = make(tmp_path, v_rel_sd=0.0, f_col_sd_hz=0.0)
    ds = load_dataset(ds_path)
    truth = json.loads(truth_path.read_text())["twin_means"]
    for r in ds.summary.itertuples():
        assert float(r.v_mean_m_s) == pytest.approx(truth[r.condition_id]["v_mean_m_s"], rel=1e-9)
        assert float(r.f_col_hz) == pytest.approx(truth[r.condition_id]["f_col_hz"], abs=1e-9)


def test_noise_has_the_stated_size(tmp_path):
    """Over many seeds the relative v deviation from the twin's mean has sd v_rel_sd."""
    devs = []
    for seed in range(12):
        ds_path, truth_path = make(tmp_path, seed=seed, v_rel_sd=0.02, f_col_sd_hz=1.0,
                                   out_dir=tmp_path / ("ds%d" % seed))
        ds = load_dataset(ds_path)
        truth = json.loads(truth_path.read_text())["twin_means"]
        devs += [float(r.v_mean_m_s) / truth[r.condition_id]["v_mean_m_s"] - 1
                 for r in ds.summary.itertuples()]
    sd = np.std(devs, ddof=1)
    assert 0.015 < sd < 0.026  # 96 draws: sd of the sd estimate ~7 %


def test_unknown_effect_fails_before_any_run(tmp_path):
    with pytest.raises(twin_config.ConfigError, match="unknown effect"):
        make_hidden_dataset("h", {"no_such_effect": {}}, runner=run_fake_twin,
                            runs_dir=tmp_path / "runs", out_dir=tmp_path / "ds",
                            truth_dir=tmp_path / "t")
    assert not (tmp_path / "runs").exists() and not (tmp_path / "ds").exists()


def test_effect_spec_parsing_and_cli_errors(capsys):
    assert parse_effect("viscoelastic_restitution:k=0.05") == ("viscoelastic_restitution",
                                                                {"k": 0.05})
    assert main(["--name", "x", "--effect", "air_drag:drag_scale=abc", "--fake"]) == 2
    assert "not a number" in capsys.readouterr().err
