"""No command deletes or overwrites anything it did not write: every refused --out of the loop
and every other folder-writing stage gives exit 2, one line, and leaves the whole tree byte for
byte as it was; the refusal comes before any work."""
import hashlib
import json
import shutil
from pathlib import Path

import pytest

from analysis import loop
from analysis.atomic_dir import (MARKER, OutputError, check_out_dir, output_dir, publish_dir,
                                 staging_dir)
from analysis.config import PAPER_TABLE3_DIR, REPO_ROOT, RUNS_DIR


def tree_hash(root: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        h.update(str(p.relative_to(root)).encode())
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()


@pytest.fixture
def world(tmp_path, monkeypatch):
    ds = tmp_path / "work" / "mydata"
    shutil.copytree(PAPER_TABLE3_DIR, ds)
    (tmp_path / "work" / "notes").mkdir()
    (tmp_path / "work" / "notes" / "thesis.tex").write_text("precious")
    (tmp_path / "work" / "file.txt").write_text("a file")
    monkeypatch.chdir(tmp_path / "work")
    return tmp_path / "work", ds


REFUSED = {
    "dot": lambda w, ds: ".",
    "the dataset": lambda w, ds: str(ds),
    "inside the dataset": lambda w, ds: str(ds / "out"),
    "holds the dataset": lambda w, ds: str(w),
    "unmarked folder": lambda w, ds: str(w / "notes"),
    "a file": lambda w, ds: str(w / "file.txt"),
    "the repository": lambda w, ds: str(REPO_ROOT),
    "sources": lambda w, ds: str(REPO_ROOT / "analysis"),
    "data": lambda w, ds: str(REPO_ROOT / "data" / "measurements" / "x"),
    "run cache": lambda w, ds: str(RUNS_DIR),
}


def _commands(out, ds):
    return {
        "loop": lambda: loop.main(["--dataset", str(ds), "--out", out, "--fake",
                                   "--workers", "1"]),
    }


@pytest.mark.parametrize("case", sorted(REFUSED))
@pytest.mark.parametrize("command", ["loop"])
def test_refused_out_leaves_everything_untouched(world, case, command, capsys):
    w, ds = world
    out = REFUSED[case](w, ds)
    before = tree_hash(w)
    repo_before = tree_hash(REPO_ROOT / "data")
    rc = _commands(out, ds)[command]()
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "--out" in err and len(err.strip().splitlines()) == 1, err
    assert tree_hash(w) == before
    assert tree_hash(REPO_ROOT / "data") == repo_before


def test_own_output_is_replaced_and_marked(tmp_path):
    out = tmp_path / "o"
    tmp = staging_dir(out)
    (tmp / "a.txt").write_text("1")
    publish_dir(tmp, out)
    assert (out / MARKER).exists() and (out / "a.txt").read_text() == "1"
    tmp = staging_dir(out)                      # ours: may be replaced
    (tmp / "b.txt").write_text("2")
    publish_dir(tmp, out)
    assert not (out / "a.txt").exists() and (out / "b.txt").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]     # nothing left behind
    (tmp_path / "theirs").mkdir()
    (tmp_path / "theirs" / "x").write_text("x")
    with pytest.raises(OutputError, match="did not write"):
        check_out_dir(tmp_path / "theirs")
    check_out_dir(tmp_path / "empty_or_new")   # a new folder is fine


# --------------------------------------------------------------------------------------------
# every other folder-writing stage: the same refusals, checked before any work
# --------------------------------------------------------------------------------------------
def _stages():
    from analysis import calibrate, kinetics, predict, report
    from analysis import sensitivity, surrogate, yield_data, yield_dataset
    from analysis.kinetics import cli as kinetics_cli
    yd = yield_data
    # stage: (module, argv(out, ctx), [(module, name) of its work: must not run],
    #         ctx -> the input it reads)
    return {
        "calibrate": (calibrate, lambda o, c: ["--fake", "--dataset", str(c["ds"]), "--out", o],
                      [(calibrate, "load_dataset"), (calibrate, "calibrate")],
                      lambda c: c["ds"]),
        "kinetics": (kinetics, lambda o, c: ["--yields", str(c["yields"]), "--out", o],
                     [(yield_dataset, "load_yield_dataset"), (kinetics_cli, "fit_kinetics")],
                     lambda c: c["yields"]),
        "predict": (predict, lambda o, c: ["--compare", "--yields", str(c["yields"]), "--out", o],
                    [(yd, "load_yield_dataset"), (predict, "load_kinetics"),
                     (predict, "compare_yield_sources")], lambda c: c["yields"]),
        "surrogate": (surrogate, lambda o, c: ["--twin-table", str(c["ds"] / "summary.csv"),
                                               "--out", o],
                      [(surrogate, "load_twin_table"), (surrogate, "train_surrogates")],
                      lambda c: c["ds"]),
        "sensitivity": (sensitivity, lambda o, c: ["--fake", "--runs-dir", str(c["ds"]),
                                                   "--out", o],
                        [(sensitivity, "grid_study")], lambda c: c["ds"]),
        "yield_data": (yd, lambda o, c: ["generate", "--out", o],
                       [(yd, "synthetic_energy_inputs"), (yd, "generate_synthetic_yields")],
                       lambda c: c["yields"]),
        "report": (report, lambda o, c: ["--results-dir", o],
                   [(report, "render_page"), (report, "write_atomic")], lambda c: c["ds"]),
    }


STAGE_OUTS = {
    "dot": lambda w, c, inp: ".",
    "the repository": lambda w, c, inp: str(REPO_ROOT),
    "the input": lambda w, c, inp: str(inp),
    "unmarked folder": lambda w, c, inp: str(w / "notes"),
}


@pytest.fixture
def stage_world(world):
    w, ds = world
    from analysis.yield_data import SYNTHETIC_DATASET_DIR
    shutil.copytree(SYNTHETIC_DATASET_DIR, w / "yields")
    return w, {"ds": ds, "yields": w / "yields"}


@pytest.mark.parametrize("case", sorted(STAGE_OUTS))
@pytest.mark.parametrize("stage", sorted(_stages()))
def test_stage_refuses_out_before_any_work(stage_world, stage, case, capsys, monkeypatch):
    w, ctx = stage_world
    module, argv, work, inp = _stages()[stage]
    for mod, name in work:
        def never(*a, _what="%s.%s" % (mod.__name__, name), **k):
            pytest.fail("%s ran before the output folder was checked" % _what)
        monkeypatch.setattr(mod, name, never)
    out = STAGE_OUTS[case](w, ctx, inp(ctx))
    before = tree_hash(w)
    data_before = tree_hash(REPO_ROOT / "data")
    rc = module.main(argv(out, ctx))
    std = capsys.readouterr()
    lines = std.err.strip().splitlines()
    assert rc == 2, std
    assert len(lines) == 1 and lines[0].startswith(module.__name__ + ": error: "), std.err
    assert "Traceback" not in std.out + std.err
    assert tree_hash(w) == before
    assert tree_hash(REPO_ROOT / "data") == data_before
    target = Path(out).resolve()
    assert not list(target.parent.glob(".%s.tmp-*" % target.name))    # no staging left


def test_yield_data_refuses_a_measured_dataset_in_the_repository(capsys, monkeypatch):
    """Its file names are all among those the generator writes; it is not the generator's."""
    from analysis import yield_data as yd

    def never(*a, **k):
        pytest.fail("generated before the output folder was checked")
    monkeypatch.setattr(yd, "generate_synthetic_yields", never)
    before = tree_hash(PAPER_TABLE3_DIR)
    assert yd.main(["generate", "--out", str(PAPER_TABLE3_DIR)]) == 2
    assert "did not write" in capsys.readouterr().err
    assert tree_hash(PAPER_TABLE3_DIR) == before


@pytest.fixture
def fake_repo(tmp_path, monkeypatch):
    """A repository layout in tmp_path (results/, data/measurements/) the rule applies to."""
    from analysis import config
    repo = tmp_path / "repo"
    for name, path in (("REPO_ROOT", repo), ("RESULTS_DIR", repo / "results"),
                       ("RUNS_DIR", repo / "results" / "runs"), ("DATA_DIR", repo / "data"),
                       ("MEASUREMENTS_DIR", repo / "data" / "measurements")):
        path.mkdir(parents=True, exist_ok=True)
        monkeypatch.setattr(config, name, path)
    monkeypatch.chdir(tmp_path)
    return repo


def test_committed_unmarked_dataset_is_replaced_the_first_time(fake_repo, capsys):
    """The committed synthetic yield dataset predates the mark: the generator replaces it (and
    marks it); a measured dataset with the same file names, or the same folder outside the
    repository, is refused."""
    from analysis import yield_data as yd
    mine = fake_repo / "data" / "measurements" / yd.SYNTHETIC_DATASET_NAME
    shutil.copytree(yd.SYNTHETIC_DATASET_DIR, mine)
    assert not (mine / MARKER).exists()
    assert yd.main(["generate", "--out", str(mine), "--seed", "5"]) == 0
    assert (mine / MARKER).exists()
    assert json.loads((mine / "dataset.json").read_text())["seed"] == 5
    assert sorted(p.name for p in mine.parent.iterdir()) == [mine.name]   # nothing left over
    theirs = fake_repo / "data" / "measurements" / "table3"
    shutil.copytree(PAPER_TABLE3_DIR, theirs)
    outside = fake_repo.parent / "elsewhere"
    shutil.copytree(yd.SYNTHETIC_DATASET_DIR, outside)
    capsys.readouterr()
    for folder in (theirs, outside):
        before = tree_hash(folder)
        assert yd.main(["generate", "--out", str(folder)]) == 2
        assert "did not write" in capsys.readouterr().err
        assert tree_hash(folder) == before
    with pytest.raises(OutputError):       # names alone do not make a folder the stage's
        check_out_dir(theirs, area="datasets", own_names=yd.DATASET_FILES,
                      is_own=lambda p: False)


def test_committed_results_folder_is_replaced(fake_repo):
    """A stage's committed folder under results/ carries the mark: its stage replaces it."""
    from analysis.config import KINETICS_DIR
    old = fake_repo / "results" / "kinetics"
    shutil.copytree(KINETICS_DIR, old)
    assert (old / MARKER).exists()
    tmp = staging_dir(old)
    (tmp / "kinetics_fit.json").write_text("{}")
    publish_dir(tmp, old)
    assert (old / MARKER).exists() and sorted(p.name for p in old.iterdir()) == sorted(
        [MARKER, "kinetics_fit.json"])


def test_a_users_folder_in_results_is_refused(fake_repo):
    """results/ is where outputs live, not a licence to replace anything there: a folder a user
    made in it (no mark) is refused and left as it was."""
    mine = fake_repo / "results" / "my_notes"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="did not write"):
        with output_dir(mine) as tmp:
            (tmp / "x.csv").write_text("a\n")
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    assert (mine / "notes.txt").read_text() == "mine"


def test_the_caches_are_never_an_output(tmp_path):
    """The FAKE twin's run cache and the films' track cache are refused like the run cache."""
    from analysis.atomic_dir import check_out_file
    from analysis.config import FAKE_RUNS_DIR, TRACK_CACHE_DIR
    for cache in (FAKE_RUNS_DIR, TRACK_CACHE_DIR):
        for target in (cache, cache / "sub"):
            with pytest.raises(OutputError, match="cache"):
                check_out_dir(target)
        with pytest.raises(OutputError, match="cache"):
            check_out_file(cache / "x.csv")


def test_report_replaces_only_its_own_pages(tmp_path, capsys):
    """A results folder whose index page someone wrote by hand: refused, no page written."""
    from analysis import report
    (tmp_path / "calibration").mkdir()
    (tmp_path / "README.md").write_text("my own notes\n")
    before = tree_hash(tmp_path)
    assert report.main(["--results-dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("analysis.report: error: --results-dir")
    assert tree_hash(tmp_path) == before
    (tmp_path / "README.md").unlink()
    assert report.main(["--results-dir", str(tmp_path)]) == 0     # new pages: written
    assert report.main(["--results-dir", str(tmp_path)]) == 0     # its own pages: replaced


def test_atomic_file_replaces_only_when_complete(tmp_path):
    from analysis.atomic_dir import atomic_file
    target = tmp_path / "sub" / "table.csv"
    with atomic_file(target) as tmp:
        assert tmp.suffix == ".csv" and tmp.parent == target.parent and tmp != target
        tmp.write_text("a,b\n1,2\n")
        assert not target.exists()                 # nothing visible before the end
    assert target.read_text() == "a,b\n1,2\n"
    with pytest.raises(RuntimeError):
        with atomic_file(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("writer failed")
    assert target.read_text() == "a,b\n1,2\n"      # the old file stays, no temporary left
    assert sorted(p.name for p in target.parent.iterdir()) == ["table.csv"]
