"""The demo's twin-of-the-mill profiles (no YADE)."""
import json

import pytest

from analysis import demo
from analysis.config import twin_config


def test_profile_reaches_every_demo_run_and_bad_profiles_are_refused(tmp_path):
    assert demo.load_profile(tmp_path / "none.json")[0] is None
    p = tmp_path / "p.json"
    p.write_text(json.dumps({"config": dict(demo.PAPER_CONTACT, jar_inner_diameter_m=0.027,
                                            jar_fillet_radius_m=0.009, amplitude_m=0.0141),
                             "free": ["amplitude_m"], "dataset": "paper_dem_table3"}))
    base, words = demo.load_profile(p)
    assert "amplitude_m" in words and "paper_dem_table3" in words
    cond = demo.measured_table()
    cfgs = demo.demo_configs(cond, 2, 0.5, base)
    assert len(cfgs) == 2 * len(cond)
    for c in cfgs:
        full = twin_config.complete_config(c)
        assert full["jar_inner_diameter_m"] == 0.027 and full["amplitude_m"] == 0.0141
    # the condition keys are the demo's, whatever the profile holds
    assert {c["frequency_hz"] for c in cfgs} == set(cond["frequency_hz"])
    p.write_text(json.dumps({"config": {"jar_inner_length_m": 0.05}}))
    with pytest.raises(twin_config.ConfigError, match="needs jar_inner_diameter_m"):
        demo.load_profile(p)


def test_a_missing_calibrated_profile_is_an_error_before_any_run(tmp_path, monkeypatch, capsys):
    """The calibrated line is the twin at results/apparatus/measured_apparatus.json (committed):
    without it the demo stops with one line and exit 2, before any twin run."""
    from analysis import sweep
    from analysis.config import MEASURED_APPARATUS_PROFILE
    assert MEASURED_APPARATUS_PROFILE.is_file()

    def never(*a, **k):
        pytest.fail("a twin run started")
    monkeypatch.setattr(sweep, "run_sweep", never)
    monkeypatch.setattr(demo, "MEASURED_APPARATUS_PROFILE", tmp_path / "gone.json")
    assert demo.main(["--out", str(tmp_path / "demo"), "--no-loop"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("analysis.demo: error: ")
    assert "gone.json" in err[0] and not (tmp_path / "demo").exists()
