"""Benchmark of the YADE twin on this machine: steps/s and wall time per 0.5 s recorded.

1. steps/s at the paper's dt = 5e-7 s: jar oscillating at 25 Hz with the 20.6 mm ball in flight
   (protocol 'free', 0.1 s simulated = 200 000 steps);
2. wall seconds per 0.5 s recorded at the default dt (the recording phase of a mill run at 25 Hz)
   and for the whole run (ramp + settle + record);
3. the same whole run and the same free flight in the jar frame (run config ``frame: 'jar'``),
   and the line ``speed-up whole run: R x`` (jar frame over lab frame, measured in this one
   run; goals of the speed issue: R >= 3 and >= 100 000 steps/s at dt = 5e-7 s).
Printed beside the paper's 5 min of CPU per run (EDEM 2021.1, Intel i9-12900). Goals (issue 2):
>= 30 000 steps/s at dt = 5e-7 s and <= 10 s per 0.5 s recorded on a 2-core machine.

    python -m analysis.bench.dem
Runs are forced (not cached) and written to a temporary folder.
"""
import argparse
import sys
import tempfile

from analysis.twin import load_recording, run_twin
from analysis.config import twin_config

PAPER_S_PER_RUN = 300.0


def main(argv=None):
    argparse.ArgumentParser(prog="python -m analysis.bench.dem", description=__doc__,
                            epilog="example: python -m analysis.bench.dem",
                            formatter_class=argparse.RawDescriptionHelpFormatter
                            ).parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench-dem-") as tmp:
        a = load_recording(run_twin({"protocol": "free", "dt_s": 5e-7, "frequency_hz": 25.0,
                                     "ball_start": "random", "record_s": 0.1, "seed": 3},
                                    runs_dir=tmp, force=True))
        b = load_recording(run_twin({"frequency_hz": 25.0, "record_s": 0.5, "seed": 3},
                                    runs_dir=tmp, force=True))
        c = load_recording(run_twin({"frequency_hz": 25.0, "record_s": 0.5, "seed": 3,
                                     "frame": "jar"}, runs_dir=tmp, force=True))
        d = load_recording(run_twin({"protocol": "free", "dt_s": 5e-7, "frequency_hz": 25.0,
                                     "ball_start": "random", "record_s": 0.1, "seed": 3,
                                     "frame": "jar"}, runs_dir=tmp, force=True))
    dt = twin_config.default_config()["dt_s"]
    sps = a.meta["steps_per_s"]
    rec_s = b.meta["wall_record_s"]
    total = b.meta["wall_s"]
    print("YADE %s, jar %d facets" % (a.meta["yade_version"], a.meta["jar"]["n_facets"]))
    print("steps/s at dt = 5e-7 s:                %9.0f   (goal >= 30000: %s)"
          % (sps, "met" if sps >= 30000 else "NOT met"))
    print("wall s per 0.5 s recorded, dt = %g s: %9.1f   (goal <= 10 s: %s)"
          % (dt, rec_s, "met" if rec_s <= 10 else "NOT met"))
    print("wall s per whole run (ramp+settle+rec): %8.1f   (%.2f s simulated, %d steps, %.0f steps/s)"
          % (total, b.meta["sim_time_s"], b.meta["steps"], b.meta["steps_per_s"]))
    jt = c.meta["wall_s"]
    print("the same run in the jar frame:          %8.1f   (%.0f steps/s; %.2fx the lab frame's "
          "speed, goal 3x; v_mean %.4f vs %.4f m/s)" % (jt, c.meta["steps_per_s"], total / jt,
                                                        c.meta["summary"]["v_mean_m_s"],
                                                        b.meta["summary"]["v_mean_m_s"]))
    jsps = d.meta["steps_per_s"]
    print("steps/s at dt = 5e-7 s, jar frame:      %9.0f   (%.2fx the lab frame's; goal >= "
          "100000: %s)" % (jsps, jsps / sps, "met" if jsps >= 100000 else "NOT met"))
    print("speed-up whole run: %.2f x   (jar frame %.1f s against lab frame %.1f s; goal >= 3: %s)"
          % (total / jt, jt, total, "met" if total / jt >= 3 else "NOT met"))
    print("paper: %.0f s per run (EDEM 2021.1, i9-12900) -> this twin is %.1fx faster per run"
          % (PAPER_S_PER_RUN, PAPER_S_PER_RUN / total))
    return 0


if __name__ == "__main__":
    sys.exit(main())
