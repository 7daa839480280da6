"""analysis.twin without YADE: run folders, caching rules, reading recordings, clear errors."""
import json

import pandas as pd
import pytest

from analysis import twin
from analysis.config import twin_config


def fake_recording(path, meta=None, drop=None):
    path.mkdir(parents=True)
    traj = pd.DataFrame([[0.0] * len(twin.TRAJECTORY_COLUMNS)], columns=twin.TRAJECTORY_COLUMNS)
    imp = pd.DataFrame(columns=twin.IMPACT_COLUMNS)
    if drop:
        traj = traj.drop(columns=[drop])
    traj.to_csv(path / "trajectory.csv", index=False)
    imp.to_csv(path / "impacts.csv", index=False)
    (path / "meta.json").write_text(json.dumps(meta or {"config": {}, "summary": {}}))


def test_complete_recording_is_read(tmp_path):
    fake_recording(tmp_path / "r")
    rec = twin.load_recording(tmp_path / "r")
    assert list(rec.trajectory.columns) == twin.TRAJECTORY_COLUMNS
    assert list(rec.impacts.columns) == twin.IMPACT_COLUMNS


def test_incomplete_folder_is_not_a_recording(tmp_path):
    (tmp_path / "r").mkdir()
    with pytest.raises(FileNotFoundError, match="not a complete"):
        twin.load_recording(tmp_path / "r")


def test_missing_contract_column_is_named(tmp_path):
    fake_recording(tmp_path / "r", drop="jar_x_m")
    with pytest.raises(ValueError, match="jar_x_m"):
        twin.load_recording(tmp_path / "r")


def test_cached_recording_is_returned_without_yade(tmp_path, monkeypatch):
    cfg = {"frequency_hz": 27.5}
    rd = twin.run_dir_for(twin_config.complete_config(cfg), tmp_path)
    fake_recording(rd)
    monkeypatch.setenv("YADE", "/nonexistent/yade")  # would fail if YADE were started
    assert twin.run_twin(cfg, runs_dir=tmp_path) == rd


def test_missing_yade_is_one_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv("YADE", "/nonexistent/yade")
    with pytest.raises(twin.TwinRunError, match="apt-get install -y yade"):
        twin.run_twin({"frequency_hz": 21.0}, runs_dir=tmp_path)


def test_invalid_config_fails_before_yade(tmp_path, monkeypatch):
    monkeypatch.setenv("YADE", "/nonexistent/yade")
    with pytest.raises(twin_config.ConfigError, match="frequency_hz"):
        twin.run_twin({"frequency_hz": float("nan")}, runs_dir=tmp_path)


def test_cli_reports_bad_input(capsys):
    assert twin.main(["--frequency-hz", "-3"]) == 2
    assert "frequency_hz" in capsys.readouterr().err


def test_recording_schema_is_declared_once():
    """The scene, the run reader and the observer use the schema of yade_scripts/twin_config.py:
    the reader's columns are it, the observer's a subset of it."""
    from analysis import observe
    assert twin.TRAJECTORY_COLUMNS == list(twin_config.TRAJECTORY_COLUMNS)
    assert twin.IMPACT_COLUMNS == list(twin_config.IMPACT_COLUMNS)
    assert set(observe.TRAJECTORY_COLUMNS) <= set(twin_config.TRAJECTORY_COLUMNS)
    assert set(observe.IMPACT_COLUMNS) <= set(twin_config.IMPACT_COLUMNS)
    assert observe.CAMERA_FPS == twin_config.CAMERA_FPS
    src = (twin_config.repo_root() + "/yade_scripts/mill.py")
    text = open(src).read()
    assert "twin_config.TRAJECTORY_COLUMNS" in text and "twin_config.IMPACT_COLUMNS" in text
