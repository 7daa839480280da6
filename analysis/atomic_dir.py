"""Write a result folder completely or not at all: stage it beside its target, then swap it in."""
import os
import shutil
import tempfile
from pathlib import Path


def staging_dir(out_dir):
    """A fresh temporary folder beside ``out_dir`` (same file system, so the swap is a rename)."""
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=".%s.tmp-" % out_dir.name, dir=out_dir.parent))


def publish_dir(tmp, out_dir):
    """Move the finished folder ``tmp`` onto ``out_dir``, replacing an existing one.

    The old folder is renamed away first, so ``out_dir`` never holds a mix of old and new files.
    """
    tmp, out_dir = Path(tmp), Path(out_dir)
    if out_dir.exists():
        old = Path(tempfile.mkdtemp(prefix=".%s.old-" % out_dir.name, dir=out_dir.parent))
        os.replace(out_dir, old / out_dir.name)
        os.replace(tmp, out_dir)
        shutil.rmtree(old)
    else:
        os.replace(tmp, out_dir)
    return out_dir
