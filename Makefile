# The pipeline. `make demo` and `make test` bootstrap everything on a fresh Debian machine:
# YADE from Debian's `yade` package (apt-get when root), the analysis venv from requirements.txt.
SHELL := /bin/bash
PY ?= python3
VENV := .venv
VPY := $(VENV)/bin/python
YADE ?= yade
export PYTHONHASHSEED := 0
# one thread for BLAS in tests and sweeps: the machine has 2 cores and runs are parallel already
export OMP_NUM_THREADS ?= 1
export OPENBLAS_NUM_THREADS ?= 1

.PHONY: all setup venv yade test test-fast demo demo-fits geometry facet-study timestep-study report \
        bench-dem bench-profile bench-loop bench-loop-cached bench-tracking bench-predict bench-sweep clean help surrogate-runs surrogate \
        loop open-world open-world-full calibrate apparatus emulator-check vf-study table3-chain

help:
	@echo "make demo   - the twin on Table 3, then the loop (calibrate, diagnose and add, twin rerun) -> results/demo/README.md, results/demo/loop/"
	@echo "make demo-fits - the demo's two loops from the committed runs; the emulator fits they use -> data/twin_runs/emulator_fits/ (replayed by make demo)"
	@echo "make test   - the test suite (installs YADE and the venv when missing)"
	@echo "make loop DATASET=data/measurements/NAME [OUT=results/loop/NAME] - the whole loop on a dataset -> OUT/report.md, diagnosis.csv, staircase.csv, loop.json"
	@echo "make calibrate - calibrate C_R, SF, RF, stroke on Table 3 -> results/calibration/summary.json"
	@echo "make open-world [ONLY=\"null_p07 eff_p01\"] - the blind suite (20 no-effect, 12 one-, 6 two-effect, 10 measurement-chain datasets) and the whole loop on each (refinement and focus waves, twin reruns; about 2 h a dataset on 1 worker: 70-260 new twin runs and 30 min of analysis; resumable; open-world-full: the same) -> results/open_world/{nulls,effects,pairs,chain}/, full_loop/README.md"
	@echo "make apparatus - the twin of the real mill (screen, identification, calibration, Table-3 loops) -> results/apparatus/"
	@echo "make bench-dem | bench-profile | bench-loop | bench-loop-cached | bench-tracking | bench-predict | bench-sweep - benchmarks (print; bench-loop -> results/bench/loop_cold.txt, bench-loop-cached -> results/bench/loop_cached.txt)"
	@echo "make vf-study - what makes v/f fall from 22.5 to 30 Hz: one change at a time, both balls, 3 seeds (252 runs, about 1 h on 1 worker; cached, resumable; the committed run table holds their summaries) -> results/studies/vf_trend/"
	@echo "make table3-chain - the loop on Table 3 with the measurement chain among its candidates, at assumed v sds of 0.5, 1 and 2 % (about 1 h each on 1 worker from the committed runs) -> results/table3_chain/"
	@echo "make emulator-check - the one emulator of the twin against real twin runs (wave 0 left out in folds + the demo blind loop's runs; about 1.5 h on 2 cores from an empty cache, 3 min from the committed runs) -> results/studies/emulator_check/"
	@echo "make report - one page per study folder -> results/*/README.md, results/README.md"
	@echo "make geometry | facet-study | timestep-study - regenerate committed studies"

setup: venv yade

venv: $(VENV)/.stamp

$(VENV)/.stamp: requirements.txt
	$(PY) -m venv $(VENV)
	$(VPY) -m pip install -q --disable-pip-version-check -r requirements.txt
	touch $@

yade:
	@if command -v $(YADE) >/dev/null 2>&1; then exit 0; fi; \
	if [ "$$(id -u)" = "0" ]; then \
	  echo "installing Debian's yade package (apt-get)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq yade >/dev/null; \
	else \
	  echo "YADE is missing. Install it with: sudo apt-get update && sudo apt-get install -y yade" >&2; \
	  echo "(or set YADE=/path/to/yade; see environment.md)" >&2; exit 1; \
	fi

test: setup
	$(VPY) -m pytest -q -n 2 --dist loadgroup tests

test-fast: venv
	$(VPY) -m pytest -q -m "not yade and not slow" tests

geometry: venv
	$(VPY) -m geometry.jar --out geometry/mm400_25ml.stl

demo: setup
	$(VPY) -m analysis.demo

demo-fits: venv
	$(VPY) -m analysis.demo --remake-fits --workers 1

facet-study: setup
	$(VPY) -m analysis.studies.facet_convergence

timestep-study: setup
	$(VPY) -m analysis.studies.timestep_convergence

bench-dem: setup
	$(VPY) -m analysis.bench.dem

# where a twin run's time goes (YADE's engine timers, in flight and in contact)
bench-profile: setup
	$(VPY) -m analysis.bench.profile

# the whole loop on 6 conditions never run: empty cache, then cached
bench-loop: setup
	$(VPY) -m analysis.bench.loop_cold

bench-loop-cached: venv
	$(VPY) -m analysis.bench.loop_cached

bench-tracking: venv
	$(VPY) -m analysis.bench.tracking

bench-predict: venv
	$(VPY) -m analysis.bench.predict

bench-sweep: setup
	$(VPY) -m analysis.bench.sweep

clean:
	rm -rf results/runs/.tmp-* .pytest_cache

surrogate-runs: setup
	$(VPY) -m analysis.studies.surrogate_runs

surrogate: surrogate-runs
	$(VPY) -m analysis.surrogate --twin-table results/twin_tables/twin_table.csv \
	  --validation-table results/twin_tables/validation_table.csv
	$(VPY) -m analysis.kinetics --twin-table results/twin_tables/all_runs.csv
	$(VPY) -m analysis.predict --compare --twin-table results/twin_tables/validation_table.csv
	$(VPY) -m analysis.report

# the loop on a user's dataset: model at its conditions, calibrate, diagnose, add, twin rerun
DATASET ?= data/measurements/paper_table3
OUT ?= results/loop/$(notdir $(abspath $(DATASET)))
loop: setup
	$(VPY) -m analysis.loop --dataset $(DATASET) --out $(OUT)

# the blind suite: 20 no-effect, 12 one-effect and 6 two-effect datasets at conditions the paper
# never ran (results/open_world/{nulls,effects,pairs}; about 6 twin runs each, cached) and 10
# with a measurement chain hidden (results/open_world/chain, made from null_p10..19's tracks, no
# twin run), then the whole loop on each (the refinement waves, the focus wave and the twin
# reruns with their confirmation rounds) with the five chain entries among its candidates,
# scored against the hidden truth: results/open_world/full_loop/. Wave 0 (162 runs) is in the
# committed run table; the rest costs 70-260 new twin runs a dataset, about 25 s each on 1
# worker, and 30 min of analysis; resumable (a dataset whose loop.json exists is kept), partial
# until all 48 ran (its NOTES.md says which); ONLY="null_p07 eff_p01" runs those.
# open-world-full: the same (its earlier name).
OWD = $(VPY) -m analysis.studies.open_world_data --only none --films none
open-world: setup
	$(OWD) --out results/open_world/nulls --nulls 20
	$(OWD) --out results/open_world/effects --effects 12
	$(OWD) --out results/open_world/pairs --pairs 6
	$(OWD) --out results/open_world/chain --chain 10
	$(VPY) -m analysis.open_suite --out results/open_world/full_loop --workers 1 \
	  $(CHAIN) $(foreach n,$(ONLY),--only $(n))

open-world-full: open-world

# the one emulator of the twin (analysis/emulator.py) against real twin runs: wave 0 of the
# design at a blind dataset's conditions, leave-out of whole points and the loop's committed runs
emulator-check: setup
	$(VPY) -m analysis.studies.emulator_check --points 24 --workers 2 --heldout results/demo/blind_loop

calibrate: setup
	$(VPY) -m analysis.calibrate --out results/calibration

# the twin of the paper's mill (docs/apparatus.md): one-at-a-time screen, the apparatus
# identified from the paper's EDEM column at its contact parameters, then contact + apparatus
# calibrated on the measurements, then the loop on Table 3 with the end fillet in its catalog at
# assumed v sds of 0.5-2 % -> results/apparatus/ (about 3 h on 2 cores from an empty cache)
PAPER_CONTACT_SET = --set restitution=0.11 --set static_friction=0.7 --set rolling_friction=0.5
EDEM_LAW_SET = --set rolling_model=constant_torque --set frame=jar
apparatus: setup
	$(VPY) -m analysis.studies.apparatus_screen
	$(VPY) -m analysis.calibrate --dataset data/measurements/paper_dem_table3 \
	  --out results/apparatus/identify_paper_dem --v-rel-sd 0.01 \
	  --free amplitude_m --free jar_inner_diameter_m --free jar_fillet_radius_m \
	  --free jar_volume_m3 $(PAPER_CONTACT_SET) $(EDEM_LAW_SET) \
	  --points 40 --waves 2 --per-wave 10 --rerun-replicates 4
	$(VPY) -m analysis.studies.apparatus_identification --cal results/apparatus/identify_paper_dem \
	  --profile results/apparatus/paper_apparatus.json
	$(VPY) -m analysis.calibrate --dataset data/measurements/paper_table3 \
	  --out results/apparatus/calibrate_measured --v-rel-sd 0.01 \
	  --base-profile results/apparatus/paper_apparatus.json \
	  --free restitution --free static_friction --free rolling_friction --free amplitude_m \
	  --free jar_fillet_radius_m --points 40 --waves 2 --per-wave 10 --rerun-replicates 4
	$(VPY) -m analysis.studies.apparatus_identification --cal results/apparatus/calibrate_measured \
	  --profile results/apparatus/measured_apparatus.json
	$(VPY) -m analysis.loop --dataset data/measurements/paper_table3 --with-effect end_fillet \
	  --v-rel-sd 0.01 --out results/apparatus/loop_table3_end_fillet_sd1
	$(VPY) -m analysis.loop --dataset data/measurements/paper_table3 --with-effect end_fillet \
	  --v-rel-sd 0.005 --max-refits 1 --out results/apparatus/loop_table3_end_fillet_sd0.5
	$(VPY) -m analysis.loop --dataset data/measurements/paper_table3 --with-effect end_fillet \
	  --v-rel-sd 0.015 --max-refits 1 --out results/apparatus/loop_table3_end_fillet_sd1.5
	$(VPY) -m analysis.loop --dataset data/measurements/paper_table3 --with-effect end_fillet \
	  --v-rel-sd 0.02 --max-refits 1 --out results/apparatus/loop_table3_end_fillet_sd2
	$(VPY) -m analysis.studies.apparatus_screen

# what makes v/f fall in a rigid harmonic jar (issue 26, docs/apparatus.md): every variant x both
# balls x 22.5 / 30 Hz x 3 seeds, one YADE process at a time; a kill loses at most the running
# run, the same command resumes (--dry-run: what is cached)
vf-study: setup
	$(VPY) -m analysis.studies.vf_trend --out results/studies/vf_trend --workers 1 --seeds 3

# the loop on Table 3 with the measurement chain (docs/loop.md: smoothing window, frame rate,
# length scale, camera plane, collision count; no twin run of their own) among its candidates,
# at assumed v sds of 0.5, 1 and 2 % -> results/table3_chain/sd<pct>/ (issue 26)
CHAIN = --with-effect apparent_scale --with-effect smoothing_window --with-effect frame_rate \
        --with-effect camera_plane --with-effect collision_count
table3-chain: setup
	for sd in 0.01 0.005 0.02; do \
	  $(VPY) -m analysis.loop --dataset data/measurements/paper_table3 --workers 1 \
	    --v-rel-sd $$sd --confirm-rounds 3 $(CHAIN) --out results/table3_chain/sd$$sd || exit $$?; \
	done

# one Markdown page per study folder in results/ and the index results/README.md
report: venv
	$(VPY) -m analysis.report
