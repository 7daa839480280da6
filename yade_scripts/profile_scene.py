"""Where a twin run's time goes: YADE's per-engine timers over one run of the scene.

    yade -n -x yade_scripts/profile_scene.py --config run.json --out profile.json

Builds the scene of ``mill.py`` from a run config, switches ``O.timingEnabled`` on and runs the
whole protocol. Every ``PROBE_STEPS`` steps a probe reads each engine's accumulated time and
books the interval to 'contact' (the contact monitor in its in-contact sampling: a wall
contact younger than 1 ms) or 'flight'. Writes one JSON: per engine and per state, the wall
nanoseconds and calls, the steps of each state, the run's wall time (the timers' own cost is
in it), and the probe's own time. No recording is written.
"""
import argparse
import json
import os
import sys
import time

_SCRIPT = __file__ if __file__.endswith(".py") else sys.argv[0]
HERE = os.path.dirname(os.path.abspath(_SCRIPT))
if HERE not in sys.path:
    sys.path.insert(0, HERE)

import mill  # noqa: E402
import twin_config  # noqa: E402
from out_rule import OutRefused, check_out_file, write_atomic  # noqa: E402
from yade import O  # noqa: E402
from yade.wrapper import PyRunner  # noqa: E402

PROBE_STEPS = 50


class Probe:
    def __init__(self, twin):
        self.twin = twin
        self.last = None
        self.book = {"flight": {}, "contact": {}}
        self.steps = {"flight": 0, "contact": 0}
        self.last_iter = O.iter
        self.own_s = 0.0

    def names(self):
        out = []
        for e in O.engines:
            n = e.label or type(e).__name__
            out.append(n if n not in out else n + "_%d" % len(out))
        return out

    def read(self):
        return [(int(e.execTime), int(e.execCount)) for e in O.engines]

    def __call__(self):
        t0 = time.perf_counter()
        now = self.read()
        state = ("contact" if self.twin.monitor.iterPeriod == self.twin.k_contact
                 else "flight")
        if self.last is not None and len(self.last) == len(now):
            b = self.book[state]
            for name, (t, c), (t1, c1) in zip(self.names(), self.last, now):
                tt, cc = b.get(name, (0, 0))
                b[name] = (tt + t1 - t, cc + c1 - c)
            self.steps[state] += O.iter - self.last_iter
        self.last = now
        self.last_iter = O.iter
        self.own_s += time.perf_counter() - t0


#: keys every profile this script writes holds
PROFILE_KEYS = ("config", "steps", "wall_s", "probe_steps", "engines")


def _is_own_profile(path) -> bool:
    try:
        with open(path) as fh:
            d = json.load(fh)
    except (OSError, ValueError):
        return False
    return isinstance(d, dict) and all(k in d for k in PROFILE_KEYS)


def main(argv=None):
    p = argparse.ArgumentParser(prog="profile_scene.py")
    p.add_argument("--config", required=True)
    p.add_argument("--out", required=True)
    a = p.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        cfg = twin_config.load_config(a.config)
        # the project's output rule, before the run: never the config, never an existing
        # file that is not a profile this script wrote
        out_path = check_out_file(a.out, mill.ROOT, [a.config], is_own=_is_own_profile)
    except (twin_config.ConfigError, OutRefused) as exc:
        sys.stderr.write("profile_scene.py: error: %s\n" % exc)
        return 2
    twin, n_max = mill.build_twin(cfg)
    probe = Probe(twin)
    import __main__
    __main__.PROBE = probe
    O.engines = O.engines + [PyRunner(iterPeriod=PROBE_STEPS, command="PROBE()",
                                      label="profile_probe")]
    O.timingEnabled = True
    wall0 = time.time()
    it0 = O.iter
    mill.step_until_done(twin, n_max)
    wall = time.time() - wall0
    out = {"config": cfg, "dt_s": cfg["dt_s"], "steps": O.iter - it0, "wall_s": wall,
           "n_facets": twin.info["n_facets"], "probe_s": probe.own_s, "probe_steps": PROBE_STEPS,
           "state_steps": probe.steps,
           "engines": {s: {k: {"ns": v[0], "calls": v[1]} for k, v in b.items()}
                       for s, b in probe.book.items()},
           "done": bool(twin.done), "error": twin.error}
    write_atomic(out_path, json.dumps(out, indent=1))
    print("profile_scene.py: wrote %s (%d steps in %.1f s)" % (a.out, out["steps"], wall))
    return 0


if __name__ == "__main__":
    rc = main()
    sys.stdout.flush()
    os._exit(rc)
