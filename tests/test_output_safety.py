"""No command deletes or overwrites anything it did not write: every refused --out of the loop,
compare and diagnose gives exit 2, one line, and leaves the whole tree byte for byte as it was."""
import hashlib
import shutil
from pathlib import Path

import pytest

from analysis import compare as cmpmod
from analysis import diagnose as diagmod
from analysis import loop
from analysis.atomic_dir import MARKER, OutputError, check_out_dir, publish_dir, staging_dir
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
        "compare": lambda: cmpmod.main(["--dataset", str(ds), "--predictions",
                                        str(ds / "summary.csv"), "--out", out]),
        "diagnose": lambda: diagmod.main(["--dataset", str(ds), "--model",
                                          "analysis.twin_model:factory", "--out", out]),
    }


@pytest.mark.parametrize("case", sorted(REFUSED))
@pytest.mark.parametrize("command", ["loop", "compare", "diagnose"])
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
