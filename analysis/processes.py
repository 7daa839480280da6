"""One map over independent items, in processes when asked, with a bar on stderr."""
from __future__ import annotations


def in_processes(fn, items, n_jobs, desc, unit, progress) -> list:
    """``fn`` over ``items``, the answers in their order, in ``n_jobs`` processes when > 1,
    with a bar on stderr when ``progress``. Each item gets its own copy of ``fn`` as it was
    before the map (what a worker process unpickles), in one process too: an answer never
    depends on what the items before it left in a model's memory (an emulator's remembered
    points), so that it is the same, to the last digit, for any ``n_jobs``."""
    import cloudpickle
    from tqdm.auto import tqdm
    items = list(items)
    if int(n_jobs) > 1 and len(items) > 1:
        from joblib import Parallel, delayed
        out = Parallel(n_jobs=min(int(n_jobs), len(items)), batch_size=1,
                       return_as="generator")(delayed(fn)(x) for x in items)
    else:
        frozen = cloudpickle.dumps(fn)
        out = (cloudpickle.loads(frozen)(x) for x in items)
    return list(tqdm(out, total=len(items), desc=desc, unit=unit, disable=not progress,
                     leave=False))
