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


def test_demo_loops_make_at_most_their_budget_of_new_runs(tmp_path, monkeypatch):
    """Each demo loop runs with the budget of new twin runs it was given (the committed table
    may lack a focus wave where this machine's fit lands elsewhere); a loop that needs more
    prints its plan (a dry run) and a line saying so, and the other loop still runs."""
    from analysis import loop
    calls = []

    def fake_main(argv):
        calls.append(list(argv))
        if "--dry-run" in argv:
            return 0
        return 3 if argv[argv.index("--out") + 1].endswith("loop") and \
            not argv[argv.index("--out") + 1].endswith("blind_loop") else 0
    monkeypatch.setattr(loop, "main", fake_main)
    lines = demo.demo_loops(tmp_path, 2, 40)
    runs = [c for c in calls if "--dry-run" not in c]
    assert [c[c.index("--budget-runs") + 1] for c in runs] == ["40", "40"]
    assert sum("--dry-run" in c for c in calls) == 1
    assert "needs more than 40 new twin runs" in lines[0]
    assert lines[1].endswith("blind_loop/report.md")


def test_a_negative_loop_budget_is_refused_before_any_run(tmp_path, monkeypatch, capsys):
    from analysis import sweep

    def never(*a, **k):
        pytest.fail("a twin run started")
    monkeypatch.setattr(sweep, "run_sweep", never)
    assert demo.main(["--out", str(tmp_path / "demo"), "--loop-budget-runs", "-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--loop-budget-runs" in err[0]
