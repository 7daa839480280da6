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


def test_yields_follow_the_powder_line_and_kinetics_effects_skip_the_twin(tmp_path):
    """Yields at the stated times from the twin means through X = a E_tot + b; a kinetics
    effect changes the yields but not the twin runs (same run ids as without it)."""
    from analysis import kinetics
    ds0, t0 = make(tmp_path, yield_sd_pct=0.0, v_rel_sd=0.0, f_col_sd_hz=0.0,
                   out_dir=tmp_path / "a")
    truth0 = json.loads(t0.read_text())
    ds = load_dataset(ds0)
    assert sorted(ds.yields["time_min"].unique()) == [2.5, 5.0, 7.5, 10.0]
    r = ds.yields.iloc[-1]
    cid = r["condition_id"]
    d_m = float(ds.conditions.set_index("condition_id").loc[cid, "ball_diameter_mm"]) * 1e-3
    m = truth0["twin_means"][cid]
    e_tot = 0.5 * kinetics.ball_mass_kg(d_m) * m["v_mean_m_s"] ** 2 * m["f_col_hz"] * 600.0
    expect = max(kinetics.PAPER_SLOPE_PCT_PER_KJ * e_tot / 1000 + kinetics.PAPER_INTERCEPT_PCT, 0)
    assert float(r["yield_pct"]) == pytest.approx(expect, rel=1e-9)
    ds1, t1 = make_hidden_dataset("k", {"air_drag": {}, "induction_period":
                                        {"induction_energy_j": 400.0}},
                                  replicates=2, seed=3, runner=run_fake_twin, workers=1,
                                  runs_dir=tmp_path / "runs", out_dir=tmp_path / "b",
                                  truth_dir=tmp_path / "truth", yield_sd_pct=0.0)
    truth1 = json.loads(t1.read_text())
    assert truth1["run_ids"] == truth0["run_ids"]
    y1 = load_dataset(ds1).yields
    drop = (ds.yields["yield_pct"].to_numpy() - y1["yield_pct"].to_numpy())
    pos = y1["yield_pct"].to_numpy() > 0
    assert np.allclose(drop[pos], kinetics.PAPER_SLOPE_PCT_PER_KJ * 0.4)


def test_two_kinetics_effects_are_refused(tmp_path):
    with pytest.raises(ValueError, match="do not compose"):
        make_hidden_dataset(
            "h", {"induction_period": {}, "first_order_depletion": {}}, runner=run_fake_twin,
            runs_dir=tmp_path / "runs", out_dir=tmp_path / "ds", truth_dir=tmp_path / "t")
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize("fails", ["dataset", "truth"])
def test_a_failed_rewrite_leaves_the_earlier_dataset_and_truth_together(tmp_path, monkeypatch,
                                                                        fails):
    """Rewriting a dataset: when writing the new dataset or the new truth fails, neither file of
    the pair changes (no new dataset beside the old truth, no new truth beside the old
    dataset), and no staged file is left behind."""
    ds_path, truth_path = make(tmp_path, seed=3)
    before = ((ds_path / "summary.csv").read_text(), truth_path.read_text())
    import analysis.measurements as measurements
    from pathlib import Path
    write_text = Path.write_text

    def broken(*a, **k):
        raise OSError("disk full")

    def broken_truth(self, *a, **k):
        if self.parent == truth_path.parent:
            raise OSError("disk full")
        return write_text(self, *a, **k)
    if fails == "dataset":
        monkeypatch.setattr(measurements, "write_dataset", broken)
    else:
        monkeypatch.setattr(Path, "write_text", broken_truth)
    with pytest.raises(OSError, match="disk full"):
        make(tmp_path, seed=4)
    assert ((ds_path / "summary.csv").read_text(), truth_path.read_text()) == before
    assert sorted(p.name for p in truth_path.parent.iterdir()) == [truth_path.name]
    monkeypatch.undo()
    make(tmp_path, seed=4)
    assert (ds_path / "summary.csv").read_text() != before[0]
    assert json.loads(truth_path.read_text())["noise"]["seed"] == 4
