"""One output rule for every writer, bounds wherever a run config is built, every loop option
checked before planning (issue 27, deliverables 1, 2 and 4).

The table: one row per bad or unusual input - the scene's ``--out`` (YADE, marker ``yade``),
observe's ``--out``, flights' ``--impacts``, the loop's options, its ``--out`` and its dataset.
Each row is refused with one clear error line and a non-zero exit (2), before any work, and
no file outside the command's own output changes: the working folder (inputs, a user's
thesis, the dataset) is hashed before and after, and so is the repository folder a row aims
at. Then what is handled instead of refused: each writer replaces its own earlier output, a
single condition or a small dataset is refused or capped with a reason, Ctrl-C at any moment
is one line and exit 130, and no response config leaves the declared bounds - the loop with
the FAKE twin, fed anchors on the bounds, never exits 2 once its twin runs started.
"""
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from analysis import atomic_dir
from analysis import flights as flt
from analysis import loop
from analysis import observe as obs
from analysis import sweep
from analysis.config import PAPER_TABLE3_DIR, REPO_ROOT
from analysis.parameter_space import CALIBRATED
from yade_scripts import out_rule
from yade_scripts.twin_config import PARAMETERS, ConfigError, complete_config

MILL = REPO_ROOT / "yade_scripts" / "mill.py"
#: a free-flight run of a few milliseconds: the scene's own earlier output, made in seconds
QUICK_RUN = {"protocol": "free", "record_s": 0.005, "ball_start": "given",
             "ball_init_pos_m": [0.0, 0.0, 0.0], "ball_init_vel_m_s": [1.0, 0.0, 0.0]}


def tree_hash(root: Path) -> str:
    """Every path and file's bytes under ``root`` (``__pycache__`` left out)."""
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        if "__pycache__" in p.parts:
            continue
        h.update(str(p.relative_to(root)).encode())
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def track_frame():
    """A track with the jar (t_s, x_m, y_m, jar_x_m) of the exact 1-D impact map, 0.2 s."""
    from tests.test_flights import impact_map_track
    tr, _ = impact_map_track(record_s=0.2)
    return tr


@pytest.fixture
def work(tmp_path, monkeypatch, track_frame):
    """The working folder (cwd): a track, a user's thesis folder, a plain file, a foreign CSV,
    a copy of Table 3 and a one-condition dataset, a run config for the scene."""
    w = tmp_path / "work"
    w.mkdir()
    track_frame.to_csv(w / "track.csv", index=False)
    (w / "notes" / "sub").mkdir(parents=True)
    (w / "notes" / "thesis.tex").write_text("precious")
    (w / "notes" / "sub" / "data.csv").write_text("a,b\n1,2\n")
    (w / "file.txt").write_text("a file")
    (w / "foreign.csv").write_text("x,y\n1,2\n")
    (w / "params.csv").write_text("seed\n1\n2\n")
    shutil.copytree(PAPER_TABLE3_DIR, w / "ds")
    one = w / "one"
    shutil.copytree(PAPER_TABLE3_DIR, one)
    for name in ("conditions.csv", "summary.csv"):
        lines = (PAPER_TABLE3_DIR / name).read_text().splitlines()
        (one / name).write_text("\n".join(lines[:2]) + "\n")
    (w / "cfg.json").write_text(json.dumps(QUICK_RUN))
    (w / "in").mkdir()
    (w / "in" / "cfg.json").write_text(json.dumps(QUICK_RUN))
    (w / "bogus_effect.json").write_text(json.dumps(dict(QUICK_RUN, effects={"bogus": {}})))
    (w / "bogus_param.json").write_text(json.dumps(dict(QUICK_RUN,
                                                        effects={"air_drag": {"nope": 1}})))
    (w / "ro").mkdir()
    monkeypatch.chdir(w)
    monkeypatch.setattr("analysis.config.FAKE_RUNS_DIR", tmp_path / "fake_runs")
    return w


def _read_only(w, monkeypatch):
    """Make ``w/ro`` read-only (as root, whom the mode does not stop, the writability check
    reads the mode bits instead)."""
    os.chmod(w / "ro", 0o555)
    if os.geteuid() == 0:
        monkeypatch.setattr(atomic_dir, "_writable",
                            lambda p: bool(os.stat(p).st_mode & 0o200))


def _loop(*extra, ds="ds"):
    return ("loop", lambda w: ["--dataset", str(w / ds), "--out", str(w / "lo"), *extra])


def _loop_out(out, *extra):
    return ("loop", lambda w: ["--dataset", str(w / "ds"), "--out", out(w), "--fake",
                               "--workers", "1", *extra])


def _observe(out):
    return ("observe", lambda w: [str(w / "track.csv"), "--frequency-hz", "25", "--out",
                                  out(w)])


def _flights(out):
    return ("flights", lambda w: [str(w / "track.csv"), "--frequency-hz", "25", "--impacts",
                                  out(w)])


def _sweep(flag, out):
    return ("sweep", lambda w: ["--table", str(w / "params.csv"), "--runs-dir",
                                str(w.parent / "runs"), "--backend", "serial", "--no-progress",
                                flag, out(w)])


def _mill(out, cfg=lambda w: w / "cfg.json"):
    return ("mill", lambda w: ["--config", str(cfg(w)), "--out", out(w)])


def _own_recording_plus_stranger(w):
    """A folder holding a recording of the scene and a user's file beside it."""
    d = w / "rec"
    d.mkdir()
    (d / "meta.json").write_text(json.dumps({k: 1 for k in out_rule.SCENE_META_KEYS}))
    (d / "trajectory.csv").write_text("t_s\n")
    (d / "thesis.tex").write_text("precious")
    return str(d)


def _py(command, argv):
    """A row of a command run as ``python -m <module>`` (a subprocess)."""
    return (command, argv)


def _with_foreign_truth(w):
    """A datasets parent whose truth/null_a.truth.json is a user's file."""
    (w / "ow" / "truth").mkdir(parents=True)
    (w / "ow" / "truth" / "null_a.truth.json").write_text('{"mine": 1}')
    return str(w / "ow")


def _with_unmarked_dataset(w):
    """A datasets parent whose null_a folder holds a user's file."""
    (w / "ow2" / "null_a").mkdir(parents=True)
    (w / "ow2" / "null_a" / "thesis.tex").write_text("precious")
    return str(w / "ow2")


def _datasets(w):
    """A folder of datasets (one folder with a dataset.json) for the open suite."""
    (w / "dsets" / "x").mkdir(parents=True)
    (w / "dsets" / "x" / "dataset.json").write_text("{}")
    return str(w / "dsets")


yade = pytest.mark.yade
#: (id, (command, argv(work)), words the error line holds, repository folder it aims at,
#:  marks)
ROWS = [
    # --- the scene's --out (YADE): refused before any simulation
    ("mill-out-unmarked-folder", _mill(lambda w: str(w / "notes")),
     ["--out", "did not write", "new or empty folder"], None, [yade]),
    ("mill-out-is-a-file", _mill(lambda w: str(w / "file.txt")), ["--out", "is a file"],
     None, [yade]),
    ("mill-out-is-cwd", _mill(lambda w: "."), ["--out", "current directory"], None, [yade]),
    ("mill-out-holds-the-config", _mill(lambda w: str(w / "in"), lambda w: w / "in" / "cfg.json"),
     ["--out", "input"], None, [yade]),
    ("mill-out-is-a-source-folder", _mill(lambda w: str(REPO_ROOT / "yade_scripts")),
     ["--out", "outside results/"], REPO_ROOT / "yade_scripts", [yade]),
    ("mill-out-own-recording-plus-a-stranger", _mill(_own_recording_plus_stranger),
     ["--out", "did not write"], None, [yade]),
    # --- the scene's run config: an effect it does not know, before any output
    ("mill-unknown-effect", _mill(lambda w: str(w / "new_run"), lambda w: w / "bogus_effect.json"),
     ["unknown effect", "bogus"], None, [yade]),
    ("mill-unknown-effect-parameter",
     _mill(lambda w: str(w / "new_run"), lambda w: w / "bogus_param.json"),
     ["effect air_drag", "unknown parameter", "nope"], None, [yade]),
    ("profile-out-foreign-file", ("profile", lambda w: ["--config", str(w / "cfg.json"),
                                                        "--out", str(w / "foreign.csv")]),
     ["--out", "already exists"], None, [yade]),
    ("profile-out-is-its-config", ("profile", lambda w: ["--config", str(w / "cfg.json"),
                                                         "--out", str(w / "cfg.json")]),
     ["--out", "input"], None, [yade]),
    # --- observe --out: never the input, never a file it did not write
    ("observe-out-is-its-input-track", _observe(lambda w: str(w / "track.csv")),
     ["--out", "input"], None, []),
    ("observe-out-foreign-file", _observe(lambda w: str(w / "foreign.csv")),
     ["--out", "already exists", "not an earlier output"], None, []),
    ("observe-out-parent-is-a-file", _observe(lambda w: str(w / "file.txt" / "s.csv")),
     ["--out", "is a file"], None, []),
    ("observe-out-is-a-folder", _observe(lambda w: str(w / "notes")), ["--out", "folder"],
     None, []),
    ("observe-out-in-a-source-folder", _observe(lambda w: str(REPO_ROOT / "yade_scripts"
                                                              / "s.csv")),
     ["--out", "outside results/"], REPO_ROOT / "yade_scripts", []),
    # --- flights --impacts: the same rule
    ("flights-impacts-is-its-input-track", _flights(lambda w: str(w / "track.csv")),
     ["--impacts", "input"], None, []),
    ("flights-impacts-foreign-file", _flights(lambda w: str(w / "foreign.csv")),
     ["--impacts", "already exists"], None, []),
    ("flights-impacts-parent-is-a-file", _flights(lambda w: str(w / "file.txt" / "i.csv")),
     ["--impacts", "is a file"], None, []),
    ("flights-impacts-is-a-folder", _flights(lambda w: str(w / "notes")),
     ["--impacts", "folder"], None, []),
    ("flights-impacts-in-a-source-folder", _flights(lambda w: str(REPO_ROOT / "yade_scripts"
                                                                  / "i.csv")),
     ["--impacts", "outside results/"], REPO_ROOT / "yade_scripts", []),
    # --- the sweep's --out table and --export-yade-table: the same rule
    ("sweep-out-is-its-parameter-table", _sweep("--out", lambda w: str(w / "params.csv")),
     ["--out", "input"], None, []),
    ("sweep-out-foreign-file", _sweep("--out", lambda w: str(w / "foreign.csv")),
     ["--out", "already exists"], None, []),
    ("sweep-yade-table-is-its-parameter-table",
     _sweep("--export-yade-table", lambda w: str(w / "params.csv")),
     ["--export-yade-table", "input"], None, []),
    ("sweep-yade-table-foreign-file",
     _sweep("--export-yade-table", lambda w: str(w / "notes" / "thesis.tex")),
     ["--export-yade-table", "already exists"], None, []),
    # --- every other command that writes: its --out before any work (python -m, a subprocess)
    ("bench-profile-out-foreign-file",
     _py("bench_profile", lambda w: ["--out", str(w / "foreign.csv")]),
     ["--out", "already exists"], None, []),
    ("bench-profile-out-parent-is-a-file",
     _py("bench_profile", lambda w: ["--out", str(w / "file.txt" / "p.csv")]),
     ["--out", "is a file"], None, []),
    ("frame-equivalence-out-foreign-file",
     _py("frame_equivalence", lambda w: ["--out", str(w / "foreign")]),
     ["--out", "foreign.csv", "already exists"], None, []),
    ("frame-equivalence-out-in-a-source-folder",
     _py("frame_equivalence", lambda w: ["--out", str(REPO_ROOT / "yade_scripts" / "fe")]),
     ["--out", "outside results/"], REPO_ROOT / "yade_scripts", []),
    ("open-world-data-foreign-truth-file",
     _py("open_world_data", lambda w: ["--out", _with_foreign_truth(w), "--only", "null_a",
                                       "--films", "none"]),
     ["--out", "null_a.truth.json", "already exists"], None, []),
    ("open-world-data-unmarked-dataset-folder",
     _py("open_world_data", lambda w: ["--out", _with_unmarked_dataset(w), "--only",
                                       "null_a", "--films", "none"]),
     ["--out", "null_a", "did not write"], None, []),
    ("open-suite-out-unmarked-folder",
     _py("open_suite", lambda w: ["--datasets", _datasets(w), "--out", str(w / "notes")]),
     ["--out", "did not write"], None, []),
    ("open-suite-out-inside-its-datasets",
     _py("open_suite", lambda w: ["--datasets", _datasets(w), "--out",
                                  str(w / "dsets" / "x")]),
     ["--out", "input"], None, []),
    ("open-suite-no-datasets",
     _py("open_suite", lambda w: ["--datasets", str(w / "notes"), "--out", str(w / "os")]),
     ["--datasets", "no dataset folder"], None, []),
    ("jar-out-foreign-file", _py("jar", lambda w: ["--out", str(w / "foreign.csv")]),
     ["--out", "already exists"], None, []),
    ("jar-out-a-source-in-geometry",
     _py("jar", lambda w: ["--out", str(REPO_ROOT / "geometry" / "stl_io.py")]),
     ["--out", "already exists"], REPO_ROOT / "geometry", []),
    ("jar-out-in-a-source-folder",
     _py("jar", lambda w: ["--out", str(REPO_ROOT / "yade_scripts" / "j.stl")]),
     ["--out", "outside results/"], REPO_ROOT / "yade_scripts", []),
    # --- the loop's options, before planning (the dry run included)
    ("loop-budget-runs-negative-dry-run", _loop("--dry-run", "--budget-runs", "-1"),
     ["--budget-runs", ">= 0", "-1"], None, []),
    ("loop-workers-zero-dry-run", _loop("--dry-run", "--workers", "0"),
     ["--workers", ">= 1", "0"], None, []),
    ("loop-max-effects-negative-dry-run", _loop("--dry-run", "--max-effects", "-1"),
     ["--max-effects", ">= 0", "-1"], None, []),
    ("loop-null-draws-negative-dry-run", _loop("--dry-run", "--null-draws", "-2"),
     ["--null-draws", "-2"], None, []),
    ("loop-max-reanchor-negative-dry-run", _loop("--dry-run", "--max-reanchor", "-1"),
     ["--max-reanchor", "-1"], None, []),
    ("loop-max-refits-negative-dry-run", _loop("--dry-run", "--max-refits", "-1"),
     ["--max-refits", "-1"], None, []),
    ("loop-replicates-one", _loop("--fake", "--replicates", "1"), ["--replicates", ">= 2"],
     None, []),
    ("loop-diff-replicates-negative", _loop("--fake", "--diff-replicates", "-1"),
     ["--diff-replicates", ">= 0"], None, []),
    ("loop-rerun-replicates-zero", _loop("--fake", "--rerun-replicates", "0"),
     ["--rerun-replicates", ">= 1"], None, []),
    ("loop-alpha-nan", _loop("--dry-run", "--alpha", "nan"), ["--alpha", "(0, 1)", "nan"],
     None, []),
    ("loop-alpha-one", _loop("--fake", "--alpha", "1"), ["--alpha", "(0, 1)"], None, []),
    ("loop-record-s-zero", _loop("--dry-run", "--record-s", "0"), ["--record-s", "> 0"],
     None, []),
    ("loop-v-rel-sd-not-a-fraction", _loop("--dry-run", "--v-rel-sd", "1.5"),
     ["--v-rel-sd", "(0, 0.5)"], None, []),
    ("loop-scheduler-without-dask", _loop("--dry-run", "--scheduler", "tcp://h:8786"),
     ["--scheduler", "--backend dask"], None, []),
    ("loop-workers-not-an-integer", _loop("--dry-run", "--workers", "two"),
     ["--workers", "invalid int value", "two"], None, []),
    ("loop-unknown-option", _loop("--dry-run", "--bogus", "5"),
     ["unrecognized arguments", "--bogus"], None, []),
    ("loop-bad-set-dry-run", _loop("--dry-run", "--set", "restitution=0.3"),
     ["--set restitution", "sets this itself"], None, []),
    ("loop-seed-negative-dry-run", _loop("--dry-run", "--seed", "-1"),
     ["--seed", ">= 0", "-1"], None, []),
    ("loop-set-stl-a-folder-dry-run", _loop("--dry-run", "--set", "stl_path=results"),
     ["--set stl_path=results", "cannot read STL"], None, []),
    ("loop-set-stl-missing-dry-run", _loop("--dry-run", "--set", "stl_path=nope.stl"),
     ["--set stl_path=nope.stl", "cannot read STL"], None, []),
    ("loop-set-stl-units-wrong-dry-run", _loop("--dry-run", "--set", "stl_units=um"),
     ["--set stl_path=geometry/mm400_25ml.stl", "stl_units 'um'", "mm"], None, []),
    # --- the loop's --out: its parent too, before any work
    ("loop-out-parent-is-a-file", _loop_out(lambda w: str(w / "file.txt" / "out")),
     ["--out", "is a file"], None, []),
    ("loop-out-parent-read-only", _loop_out(lambda w: str(w / "ro" / "sub" / "out")),
     ["--out", "cannot write", "read-only"], None, []),
    ("loop-out-unmarked-folder", _loop_out(lambda w: str(w / "notes")),
     ["--out", "did not write"], None, []),
    # --- the loop's dataset: a single condition leaves no degree of freedom
    ("loop-single-condition", _loop("--fake", "--workers", "1", ds="one"),
     ["1 condition", "-2 degrees of freedom", "undefined", "more conditions"], None, []),
    ("loop-single-condition-dry-run", _loop("--dry-run", ds="one"),
     ["-2 degrees of freedom"], None, []),
]

PREFIX = {"observe": "analysis.observe: error: ", "flights": "analysis.flights: error: ",
          "sweep": "analysis.sweep: error: ",
          "loop": "analysis.loop: error: ", "mill": "mill.py: error: ",
          "profile": "profile_scene.py: error: ",
          "bench_profile": "analysis.bench.profile: error: ",
          "frame_equivalence": "frame_equivalence: error: ",
          "open_world_data": "open_world_data: error: ",
          "open_suite": "analysis.open_suite: error: ",
          "jar": "geometry.jar: error: "}
#: the commands run as ``python -m <module>`` in a subprocess
MODULES = {"bench_profile": "analysis.bench.profile",
           "frame_equivalence": "analysis.studies.frame_equivalence",
           "open_world_data": "analysis.studies.open_world_data",
           "open_suite": "analysis.open_suite",
           "jar": "geometry.jar"}


def _run(command, args):
    """(exit code, stdout, the command's own error lines) - in-process for the analysis
    commands, YADE as a subprocess for the scene."""
    if command in ("mill", "profile"):
        script = MILL if command == "mill" else MILL.with_name("profile_scene.py")
        proc = subprocess.run(["yade", "-n", "-x", str(script), *args], cwd=os.getcwd(),
                              capture_output=True, text=True, stdin=subprocess.DEVNULL,
                              timeout=300)
        own = [ln for ln in proc.stderr.splitlines() if ln.startswith(script.name + ":")]
        return proc.returncode, proc.stdout + proc.stderr, own
    if command in MODULES:
        proc = subprocess.run([sys.executable, "-m", MODULES[command], *args], cwd=os.getcwd(),
                              env=dict(os.environ, PYTHONPATH=str(REPO_ROOT)),
                              capture_output=True, text=True, stdin=subprocess.DEVNULL,
                              timeout=120)
        return proc.returncode, proc.stdout + proc.stderr, proc.stderr.strip().splitlines()
    main = {"observe": obs.main, "flights": flt.main, "loop": loop.main,
            "sweep": sweep.main}[command]
    try:
        rc = main(args)
    except SystemExit as exc:              # argparse's own exit
        rc = exc.code
    return rc, None, None


@pytest.mark.parametrize("command, argv, words, aims_at", [
    pytest.param(*r[1], r[2], r[3], marks=r[4], id=r[0]) for r in ROWS])
def test_refused_with_one_line_and_nothing_changed(command, argv, words, aims_at, work,
                                                   monkeypatch, capsys):
    if "read-only" in words:
        _read_only(work, monkeypatch)
    args = argv(work)
    before = tree_hash(work)
    repo_before = tree_hash(aims_at) if aims_at else None
    t0 = time.time()
    rc, text, own = _run(command, args)
    out, err = capsys.readouterr()
    if own is None:
        own, text = err.strip().splitlines(), out + err
    assert rc == 2, (rc, text)
    assert len(own) == 1, text
    assert own[0].startswith(PREFIX[command]), own[0]
    for word in words:
        assert word in own[0], (word, own[0])
    assert "Traceback" not in text
    assert tree_hash(work) == before
    if aims_at:
        assert tree_hash(aims_at) == repo_before
    if command in ("mill", "profile") or command in MODULES:   # refused before any work
        assert time.time() - t0 < 60
        assert not list(work.parent.glob("**/.tmp-*"))


def test_table_has_a_row_per_case():
    assert len({r[0] for r in ROWS}) == len(ROWS) >= 30
    assert {r[1][0] for r in ROWS} == set(PREFIX)


# -------------------------------------------------------------------------------- handled
def test_scene_rule_without_yade(tmp_path, monkeypatch):
    """out_rule (standard library) on its own: what the scene may replace and what not."""
    monkeypatch.chdir(tmp_path)
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "meta.json").write_text(json.dumps({k: 1 for k in out_rule.SCENE_META_KEYS}))
    (rec / "impacts.csv").write_text("event_id\n")
    marked = tmp_path / "marked"
    marked.mkdir()
    (marked / out_rule.MARKER).write_text("")
    (marked / "anything.txt").write_text("x")
    (tmp_path / "empty").mkdir()
    for ok in (rec, marked, tmp_path / "empty", tmp_path / "new",
               REPO_ROOT / "results" / "runs" / "0123456789abcdef"):
        assert out_rule.check_run_out(str(ok), str(REPO_ROOT)) == os.path.realpath(ok)
    fake_meta = tmp_path / "fake"
    fake_meta.mkdir()
    (fake_meta / "meta.json").write_text('{"title": "my notes"}')
    for bad in (fake_meta, REPO_ROOT, REPO_ROOT / "results", REPO_ROOT / "results" / "runs",
                REPO_ROOT / "data" / "measurements", tmp_path):
        with pytest.raises(out_rule.OutRefused):
            out_rule.check_run_out(str(bad), str(REPO_ROOT))
    with pytest.raises(out_rule.OutRefused, match="input"):
        out_rule.check_run_out(str(tmp_path / "in"), str(REPO_ROOT),
                               inputs=[str(tmp_path / "in" / "cfg.json")])


@pytest.mark.yade
def test_scene_replaces_only_its_own_output(work):
    def mill(out):
        return subprocess.run(["yade", "-n", "-x", str(MILL), "--config", "cfg.json",
                               "--out", str(out)], capture_output=True, text=True,
                              stdin=subprocess.DEVNULL, timeout=300)
    out = work / "run"
    assert mill(out).returncode == 0
    first = json.loads((out / "meta.json").read_text())
    assert out_rule.is_scene_recording(str(out))
    again = mill(out)                                   # its own recording: replaced
    assert again.returncode == 0, again.stderr
    assert json.loads((out / "meta.json").read_text())["run_id"] == first["run_id"]
    marked = work / "marked"
    marked.mkdir()
    (marked / out_rule.MARKER).write_text("")
    (marked / "old.txt").write_text("an earlier output")
    assert mill(marked).returncode == 0                 # a marked folder: replaced
    assert sorted(p.name for p in marked.iterdir()) == ["impacts.csv", "meta.json",
                                                        "trajectory.csv"]
    assert not [p for p in work.iterdir() if p.name.startswith((".tmp-", ".old-"))]


def test_observe_and_flights_replace_their_own_earlier_file(work, capsys):
    track = (work / "track.csv").read_bytes()
    for main, flag, name in ((obs.main, "--out", "summary.csv"),
                             (flt.main, "--impacts", "impacts.csv")):
        target = work / "results" / name
        for _ in range(2):                              # new, then its own: replaced
            assert main([str(work / "track.csv"), "--frequency-hz", "25", flag,
                         str(target)]) == 0, capsys.readouterr().err
        assert target.is_file()
    assert (work / "track.csv").read_bytes() == track
    assert list(pd.read_csv(work / "results" / "impacts.csv").columns) == list(
        flt.IMPACT_TABLE_COLUMNS)
    assert not [p for p in (work / "results").iterdir() if p.name.startswith(".")]


def test_sweep_replaces_its_own_tables(work, capsys):
    runner = "analysis.fake_twin:run_fake_twin"
    for flag, name in (("--export-yade-table", "runs.table"), ("--out", "sweep.csv")):
        for _ in range(2):                              # new, then its own: replaced
            assert sweep.main(["--table", str(work / "params.csv"), "--runner", runner,
                               "--runs-dir", str(work.parent / "runs"), "--backend", "serial",
                               "--no-progress", flag, str(work / "results" / name)]) == 0, \
                capsys.readouterr().err
    assert (work / "params.csv").read_text() == "seed\n1\n2\n"


def test_dof_refused_or_capped_before_planning(work):
    from analysis.measurements import load_dataset
    with pytest.raises(ValueError, match="-2 degrees of freedom"):
        loop.dof_limits(load_dataset(work / "one"), 3)
    two = work / "two"
    shutil.copytree(work / "ds", two)
    for name in ("conditions.csv", "summary.csv"):
        lines = (work / "ds" / name).read_text().splitlines()
        (two / name).write_text("\n".join(lines[:3]) + "\n")
    # 2 conditions: v and f_col each for 4 base parameters (the priors bound the design, they
    # are no pseudo-observations): 0 dof, refused
    with pytest.raises(ValueError, match="leave 0 degrees of freedom"):
        loop.dof_limits(load_dataset(two), 3)
    three = work / "three"
    shutil.copytree(work / "ds", three)
    for name in ("conditions.csv", "summary.csv"):
        lines = (work / "ds" / name).read_text().splitlines()
        (three / name).write_text("\n".join(lines[:4]) + "\n")
    assert loop.dof_limits(load_dataset(three), 3) == (2, 1)
    dof, n = loop.dof_limits(load_dataset(work / "ds"), 3)
    assert dof == 2 * 8 - 4 and n == 3


def test_loop_dry_run_on_three_conditions_says_the_effects_are_capped(work, capsys):
    two = work / "three"
    shutil.copytree(work / "ds", two)
    for name in ("conditions.csv", "summary.csv"):
        lines = (work / "ds" / name).read_text().splitlines()
        (two / name).write_text("\n".join(lines[:4]) + "\n")
    assert loop.main(["--dataset", str(two), "--out", str(work / "lo"), "--dry-run",
                      "--fake"]) == 0
    err = capsys.readouterr().err
    assert "at most 1 effect(s) added" in err and "Traceback" not in err


def test_ctrl_c_during_the_imports_is_one_line_and_130(work):
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    p = subprocess.Popen([sys.executable, "-m", "analysis.loop", "--dataset",
                          str(PAPER_TABLE3_DIR), "--out", str(work / "lo"), "--dry-run"],
                         cwd=str(work), env=env, stdout=subprocess.PIPE,
                         preexec_fn=_default_sigint,
                         stderr=subprocess.PIPE, text=True)
    _wait_until_sigint_is_caught(p.pid)    # the interpreter is up (not a fixed sleep: on a
    time.sleep(0.3)                        # loaded machine its start alone can take 1 s);
    p.send_signal(signal.SIGINT)           # the imports take seconds
    out, err = p.communicate(timeout=120)
    lines = err.strip().splitlines()
    assert p.returncode == 130, (p.returncode, err)
    assert len(lines) == 1 and lines[0].startswith("analysis.loop: interrupted"), err
    assert not (work / "lo").exists()


def test_ctrl_c_while_the_dataset_loads_is_one_line_and_130(work, monkeypatch, capsys):
    def interrupted(*a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(loop, "load_dataset", interrupted)
    assert loop.main(["--dataset", str(work / "ds"), "--out", str(work / "lo"),
                      "--dry-run"]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("analysis.loop: interrupted"), err


def test_ctrl_c_while_parsing_is_one_line_and_130(work, monkeypatch, capsys):
    def interrupted(self, *a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(loop._Parser, "parse_args", interrupted)
    assert loop.main(["--dataset", "x", "--out", "y"]) == 130
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


# ---------------------------------------------------------------------------- bounds
def _bounds(p):
    """Anchors on every bound of ``p``: the calibration's prior range and the run config's
    physical bounds (an open one - restitution's 0 - just inside)."""
    lo, hi = PARAMETERS[p][1], PARAMETERS[p][2]
    out = list(CALIBRATED[p])
    for b, inward in ((lo, 1), (hi, -1)):
        try:
            complete_config({p: b})
            out.append(b)
        except ConfigError:
            out.append(b + inward * 1e-4)
    return out


def _valid(cfg) -> bool:
    try:
        complete_config(cfg)
    except ConfigError:
        return False
    return True


@pytest.fixture(scope="module")
def fake_dataset(tmp_path_factory):
    """A FAKE-twin dataset at the issue's three conditions (22.3 Hz / 19 mm, 22.7 / 16,
    22.1 / 22), no yields."""
    from analysis.fake_twin import run_fake_twin
    from analysis.hidden import make_hidden_dataset
    d = tmp_path_factory.mktemp("fake_ds")
    conds = pd.DataFrame({"condition_id": ["a", "b", "c"],
                          "frequency_hz": [22.3, 22.7, 22.1],
                          "ball_diameter_mm": [19.0, 16.0, 22.0]})
    ds, _ = make_hidden_dataset(
        "bounds", {}, conditions=conds, replicates=1, seed=3,
        base_config={"restitution": 0.32, "static_friction": 0.55, "rolling_friction": 0.35,
                     "amplitude_m": 0.0131},
        runner=run_fake_twin, runs_dir=d / "runs", out_dir=d / "ds", truth_dir=d / "truth",
        twin_v_rel_sd=0.015, twin_f_col_sd_hz=0.5, progress=False, v_rel_sd=0.005,
        yield_times_min=())
    return ds


def test_the_design_builds_no_config_outside_the_bounds():
    """Every wave-0 run of the loop's design (the priors' Latin hypercube, one effect on in
    half the points, the reference point) is a config the run config accepts - also with the
    reference point on every calibration bound at once."""
    from analysis.emulated_twin import EmulatedTwin
    from analysis.history_matching import design_runs, initial_design
    conds = pd.DataFrame({"condition_id": ["a", "b"], "frequency_hz": [22.3, 28.0],
                          "ball_diameter_mm": [19.0, 16.0]})
    ds = type("D", (), {"conditions": conds})
    sp = loop.loop_space(ds)
    pts = initial_design(sp, 40, 0)
    runs = design_runs(sp, pts, conds, seeds=(0,))
    for corner in (0, 1):
        m = EmulatedTwin(conds, sp, theta_ref={k: v[corner] for k, v in CALIBRATED.items()})
        ref = m.point(m.theta_ref)
        ref.insert(0, "point", -1)
        runs = pd.concat([runs, design_runs(sp, ref, conds, seeds=(500,))])
    bad = [c for c in runs["config"] if not _valid(c)]
    assert not bad, bad[:1]
    assert len(runs) == 2 * 40 + 2 * 2


@pytest.mark.slow
def test_dry_run_counts_the_runs_the_loop_then_makes(fake_dataset, tmp_path, monkeypatch,
                                                     capsys):
    """With no refinement wave and one rerun the dry run's total is exact (wave 0, the focus
    wave, the rerun): the number of runs the loop then makes on the FAKE twin (the waves'
    count is a most)."""
    runs = tmp_path / "fake_runs"
    monkeypatch.setattr("analysis.config.FAKE_RUNS_DIR", runs)
    opts = ["--dataset", str(fake_dataset), "--out", str(tmp_path / "out"), "--fake",
            "--workers", "1", "--null-draws", "0", "--rerun-replicates", "1", "--points", "12",
            "--waves", "0", "--confirm-rounds", "1", "--no-intervals"]
    assert loop.main(opts + ["--dry-run"]) == 0
    total = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("total: ")]
    assert len(total) == 1
    planned = int(total[0].split()[3])
    assert loop.main(opts) == 0, capsys.readouterr().err[-2000:]
    assert len(list(runs.glob("*/meta.json"))) == planned == (12 + 3) * 3 + 6 * 3 + 3


def test_a_failing_twin_run_is_one_line_and_not_the_bad_input_code(work, monkeypatch, capsys):
    """Fault injection: every twin run fails (as a ball that leaves the jar does). The loop
    says so in one line and exits 1 - not 2, the code of a bad input, after its runs."""
    import analysis.fake_twin as fake

    def failing(config, runs_dir=None, force=False):
        raise RuntimeError("the ball left the jar at t = 0.01 s")
    monkeypatch.setattr(fake, "run_fake_twin", failing)
    rc = loop.main(["--dataset", str(work / "ds"), "--out", str(work / "lo"), "--fake",
                    "--workers", "1", "--backend", "serial"])
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("analysis.loop")]
    assert rc == 1, err
    assert len(err) == 1 and "failed" in err[0] and "left the jar" in err[0], err
    assert not (work / "lo").exists()


@pytest.mark.slow
def test_a_design_point_the_twin_cannot_run_is_left_out(fake_dataset, tmp_path, monkeypatch,
                                                         capsys):
    """Fault injection: the twin fails at one wave-0 design point (the top restitution stratum
    of 12 Latin-hypercube points: every condition, as a ball that leaves the jar at a corner of
    the design does) - 1 run in 15 of the wave, under the 25 % the loop tolerates. The loop
    leaves those runs out of the emulator, says so in one line, names them in loop.json and
    ends normally; the same loop again reads them as failed from the cache and does the same."""
    import analysis.fake_twin as fake
    real = fake.run_fake_twin

    def flaky(config, runs_dir=None, force=False):
        if config.get("seed") == 0 and config["restitution"] > 0.65:
            raise RuntimeError("the ball left the jar at t = 0.3 s")
        return real(config, runs_dir=runs_dir, force=force)
    monkeypatch.setattr(fake, "run_fake_twin", flaky)
    monkeypatch.setattr("analysis.config.FAKE_RUNS_DIR", tmp_path / "fake_runs")
    opts = ["--dataset", str(fake_dataset), "--fake", "--workers", "1", "--backend", "serial",
            "--null-draws", "0", "--rerun-replicates", "1", "--points", "12", "--waves", "0",
            "--focus-points", "2", "--confirm-rounds", "1", "--no-intervals"]
    for k in (1, 2):
        out = tmp_path / ("out%d" % k)
        assert loop.main(opts + ["--out", str(out)]) == 0, capsys.readouterr().err[-2000:]
        err = capsys.readouterr().err
        assert "failed and are left out of the model" in err and "left the jar" in err
        info = json.loads((out / "loop.json").read_text())
        n_cond = len(info["conditions"])
        assert len(info["failed_runs"]) == n_cond
        assert {r["wave"] for r in info["failed_runs"]} == {0}
        runs = pd.read_csv(out / "model_runs.csv")
        assert not runs["run_id"].isin([r["run_id"] for r in info["failed_runs"]]).any()


def test_the_other_writers_accept_their_own_earlier_output(work):
    """What each writer of the table's python -m rows replaces: its own earlier file or folder
    (the refusals are the table's), checked without any run."""
    from analysis import open_suite
    from analysis.bench import profile
    from analysis.hidden import check_outputs as hidden_outputs
    from analysis.studies import frame_equivalence as fe
    from geometry import jar
    res = work / "res"
    res.mkdir()
    (res / "prof.csv").write_text(",".join(profile.COLUMNS) + "\n")
    assert profile.check_out(res / "prof.csv") == (res / "prof.csv").resolve()
    (res / "fe.csv").write_text(",".join(fe.TABLE_HEAD) + ",v_mean_m_s_lab\n")
    (res / "fe.md").write_text(fe.PAGE_TITLE + ", 8 paper conditions x 3 seeds\n")
    assert fe.check_outputs(res / "fe")[1] == (res / "fe.md").resolve()
    (res / "fe.md").write_text("# my notes\n")
    with pytest.raises(atomic_dir.OutputError, match="already exists"):
        fe.check_outputs(res / "fe")
    (res / "truth").mkdir()
    (res / "truth" / "d.truth.json").write_text(json.dumps(
        {"name": "d", "effects": {}, "base_config": {}, "noise": {}, "run_ids": []}))
    assert hidden_outputs("d", res / "d", res / "truth")[1].name == "d.truth.json"
    # the suite's folder from before the mark: marked loop folders and its own files only
    suite = work / "suite"
    (suite / "null_a").mkdir(parents=True)
    (suite / "null_a" / atomic_dir.MARKER).write_text("")
    (suite / "summary.csv").write_text("dataset\n")
    assert open_suite._suite_folder(suite)
    (suite / "thesis.tex").write_text("precious")
    assert not open_suite._suite_folder(suite)
    # the jar: a new STL, then its own replaced; never another file
    out = res / "jar.stl"
    for _ in range(2):
        assert jar.main(["--out", str(out), "--n-circ", "16"]) == 0
    assert out.read_bytes()[:80].startswith(b"binary STL: " + jar.STL_NAME.encode()[:20])
    assert jar.check_out(REPO_ROOT / "geometry" / "mm400_25ml.stl")   # the committed jar
    assert jar.main(["--out", str(work / "foreign.csv")]) == 2
    assert (work / "foreign.csv").read_text() == "x,y\n1,2\n"


def _wait_until_sigint_is_caught(pid, timeout_s=20.0):
    """Wait until process ``pid`` catches SIGINT (Linux: bit 2 of SigCgt in /proc/<pid>/status):
    Python has installed a handler, so a Ctrl-C now meets Python, not the default disposition."""
    t_end = time.time() + timeout_s
    while time.time() < t_end:
        try:
            for line in Path("/proc/%d/status" % pid).read_text().splitlines():
                if line.startswith("SigCgt:") and int(line.split()[1], 16) & (1 << 1):
                    return
        except OSError:
            return
        time.sleep(0.01)


def _default_sigint():
    """The child starts with Ctrl-C's default disposition, as from a shell: a test process
    that ignores SIGINT (a worker of the parallel test run can) would hand that on."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _python(code):
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=60, cwd=str(REPO_ROOT), preexec_fn=_default_sigint)


def test_ctrl_c_while_the_package_loads_is_one_line_and_130():
    """The package's own handler (python -m analysis.<command>, before the command's module
    runs): one line ``analysis: interrupted``, exit 130. Simulated: argv[0] is '-m' while the
    package is imported, then SIGINT arrives before any module of the command runs."""
    proc = _python("import sys; sys.argv[0] = '-m'\n"
                   "import analysis, os, signal, time\n"
                   "os.kill(os.getpid(), signal.SIGINT)\n"
                   "time.sleep(5)\nprint('not interrupted')")
    assert proc.returncode == 130, (proc.returncode, proc.stderr)
    assert proc.stderr.strip().splitlines() == ["analysis: interrupted"], proc.stderr
    assert proc.stdout == ""


def test_the_package_handler_hands_ctrl_c_back_once_the_command_runs():
    """Once the command's module runs (``__main__`` has its spec), Ctrl-C is Python's
    KeyboardInterrupt again, so each command's own handling applies; imported any other way
    (here, the test process) the package installs nothing."""
    import analysis
    proc = _python("import sys; sys.argv[0] = '-m'\n"
                   "import analysis, os, signal, time\n"
                   "assert signal.getsignal(signal.SIGINT) is analysis._interrupted_at_start\n"
                   "sys.modules['__main__'].__spec__ = object()\n"
                   "try:\n    os.kill(os.getpid(), signal.SIGINT); time.sleep(5)\n"
                   "except KeyboardInterrupt:\n"
                   "    print('KeyboardInterrupt',\n"
                   "          signal.getsignal(signal.SIGINT) is signal.default_int_handler)\n")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["KeyboardInterrupt", "True"], proc.stdout + proc.stderr
    assert signal.getsignal(signal.SIGINT) is not analysis._interrupted_at_start
    plain = _python("import analysis, signal\n"
                    "print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)")
    assert plain.stdout.strip() == "True", plain.stderr
