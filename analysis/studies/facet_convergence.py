"""Facet-count convergence of the twin: v_mean and f_col against the jar mesh's resolution.

Meshes with 16, 24, 32 and 48 segments round (220 to 1148 facets) of the same 25.0 mL cavity;
20.6 and 17.5 mm balls at 25 Hz, paper contact parameters, replicates differing in the ball's
start position. Writes results/studies/facet_convergence.csv and prints it.

    python -m analysis.studies.facet_convergence [--seeds 2] [--workers 2]
"""
import argparse
import sys

from analysis.config import STUDIES_DIR, REPO_ROOT
from analysis.studies.common import STUDY_PROTOCOL, replicate_stats
from geometry.jar import make_jar
from geometry.stl_io import write_stl

N_CIRC = (16, 24, 32, 48)


def mesh_path(n_circ):
    return STUDIES_DIR / "meshes" / ("jar_n%d.stl" % n_circ)


def build_meshes(levels=N_CIRC):
    (STUDIES_DIR / "meshes").mkdir(parents=True, exist_ok=True)
    n_facets = {}
    for n in levels:
        tri, _ = make_jar(n_circ=n)
        write_stl(str(mesh_path(n)), tri * 1e3, name="jar n_circ=%d (mm)" % n)
        n_facets[n] = len(tri)
    return n_facets


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                epilog="example: python -m analysis.studies.facet_convergence "
                                "--seeds 2 --workers 2")
    p.add_argument("--seeds", type=int, default=2,
                   help="start positions per mesh and ball [seeds] (default %(default)s)")
    p.add_argument("--workers", type=int, default=2,
                   help="parallel twin runs [processes] (default %(default)s)")
    p.add_argument("--frequency-hz", type=float, default=25.0,
                   help="jar frequency [Hz] (default %(default)s)")
    a = p.parse_args(argv)
    from analysis.sweep import run_sweep
    n_facets = build_meshes()
    configs = []
    for n in N_CIRC:
        for d in (0.0206, 0.0175):
            for seed in range(a.seeds):
                cfg = dict(STUDY_PROTOCOL, frequency_hz=a.frequency_hz, ball_diameter_m=d,
                           seed=seed, stl_path=str(mesh_path(n).relative_to(REPO_ROOT)))
                configs.append(cfg)
    res = run_sweep(configs, workers=a.workers)
    t = res.table.copy()
    t["n_circ"] = [int(str(c).split("_n")[1].split(".")[0]) for c in t["stl_path"]]
    t["key"] = t["n_circ"].astype(str) + "_" + (t["ball_diameter_m"] * 1e3).round(1).astype(str)
    stats = replicate_stats(t, "key")
    stats["n_circ"] = [int(k.split("_")[0]) for k in stats["key"]]
    stats["ball_diameter_mm"] = [float(k.split("_")[1]) for k in stats["key"]]
    stats["n_facets"] = stats["n_circ"].map(n_facets)
    sps = t.groupby("n_circ")["exec_s"].mean()
    stats["wall_s_per_run"] = stats["n_circ"].map(sps)
    stats = stats.drop(columns="key").sort_values(["ball_diameter_mm", "n_circ"])
    ref = stats[stats["n_circ"] == max(N_CIRC)].set_index("ball_diameter_mm")
    stats["v_mean_diff_vs_finest_pct"] = [
        100 * (r.v_mean_m_s_mean / ref.loc[r.ball_diameter_mm, "v_mean_m_s_mean"] - 1)
        for r in stats.itertuples()]
    STUDIES_DIR.mkdir(parents=True, exist_ok=True)
    out = STUDIES_DIR / "facet_convergence.csv"
    stats.to_csv(out, index=False, float_format="%.5g")
    print(stats.to_string(index=False))
    print("wrote", out)
    return 0 if res.ok else 1


if __name__ == "__main__":
    sys.exit(main())
