"""OpenBLAS's kernels are pinned before NumPy loads (analysis/__init__.py): the Haswell (AVX2 +
FMA) kernels on every x86-64 processor that has them, one BLAS thread, a user's own setting
kept."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from analysis import PINNED_KERNELS, _cpu_flags, pin_kernels

REPO = Path(__file__).resolve().parents[1]


def test_pins_only_where_the_processor_runs_them_and_keeps_the_users_setting():
    env = {"OPENBLAS_NUM_THREADS": "4"}
    assert pin_kernels(env, flags={"sse2", "avx2", "fma"}) == {"OPENBLAS_CORETYPE": "Haswell"}
    assert env == {"OPENBLAS_NUM_THREADS": "4", "OPENBLAS_CORETYPE": "Haswell"}
    env = {}
    assert pin_kernels(env, flags={"avx512f", "avx2", "fma"}) == PINNED_KERNELS == env
    for flags in ({"sse2", "avx"}, {"avx2"}, set()):         # no AVX2 + FMA: nothing set
        env = {}
        assert pin_kernels(env, flags=flags) == {} and env == {}


def _loaded(env):
    code = ("import analysis, json, numpy, threadpoolctl; "
            "print(json.dumps([[d['internal_api'], d.get('architecture'), d['num_threads']] "
            "for d in threadpoolctl.threadpool_info()]))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not {"avx2", "fma"} <= _cpu_flags(), reason="no AVX2 + FMA here")
def test_a_fresh_process_runs_the_pinned_kernels():
    env = {k: v for k, v in os.environ.items() if k not in PINNED_KERNELS}
    libs = [d for d in _loaded(env) if d[0] == "openblas"]
    assert libs and all(arch == "Haswell" and n == 1 for _, arch, n in libs), libs
    # a user's own choice wins
    libs = [d for d in _loaded(dict(env, OPENBLAS_CORETYPE="Sandybridge")) if d[0] == "openblas"]
    assert all(arch == "Sandybridge" for _, arch, _ in libs), libs
