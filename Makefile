# blenav: `make demo` runs the main job on the built-in default, `make test` runs the test suite.
# Both create .venv when it is missing. torch is pinned to the CPU wheel before the package installs,
# so pip never pulls a CUDA build (pyproject only asks torch>=2.13).
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
STAMP   = $(VENV)/.blenav-installed
DEMO   ?= data/demo

.PHONY: install demo test test-slow test-all bench realism paper-tables crossphone-tables clean-demo

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e '.[dev]'
	@touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/blenav-sim sim=office_45x55 seed=0 out=$(DEMO)/dataset duration_s=240 sessions=3 \
	    'sim.carriers=[pedestrian,robot,static]' overwrite=true
	$(BIN)/blenav-validate $(DEMO)/dataset
	$(BIN)/blenav-plot $(DEMO)/dataset --out $(DEMO)/report
	$(BIN)/blenav-eval experiment=mapfusion_002 data=$(DEMO)/dataset runs=20 out=$(DEMO)/report/mapfusion_002
	@echo "demo report: $(DEMO)/report (dataset plots, results.md and plots of the localization comparison)"

test: $(STAMP)
	$(BIN)/python -m pytest -q

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -m ""

bench: $(STAMP)
	$(BIN)/python benchmarks/sim_speed.py
	$(BIN)/python benchmarks/filter_speed.py
	$(BIN)/python benchmarks/map_index.py
	$(BIN)/python benchmarks/onnx_speed.py
	$(BIN)/python benchmarks/crossphone_train.py
	$(BIN)/python benchmarks/mapprior_train.py

# The README's result tables: per preset, 5 sessions of 384 s with one phone model (as the papers), the
# first walk calibrates the path-loss model and is not scored, then both experiments with 100 runs.
PRESETS ?= office_45x55 campus_floor
paper-tables: $(STAMP)
	for P in $(PRESETS); do \
	  $(BIN)/blenav-sim sim=$$P seed=1 out=data/$${P}_eval duration_s=384 sessions=5 'sim.receivers=[iphone-8]' \
	      'sim.carriers=[pedestrian,pedestrian,robot,pedestrian,robot]' sim.unlabelled_every=0 overwrite=true progress=false && \
	  CAL=$$(ls data/$${P}_eval/sessions | head -1) && \
	  $(BIN)/blenav-eval experiment=mapfusion_002 data=data/$${P}_eval runs=100 calibration=[$$CAL] \
	      out=data/results/$${P}_mapfusion_002 progress=false && \
	  $(BIN)/blenav-eval experiment=frontend_000 data=data/$${P}_eval runs=100 calibration=[$$CAL] \
	      out=data/results/$${P}_frontend_000 progress=false || exit 1; \
	done

# Roy's Tables 3.3-3.5 on the simulated campus (60 ten-minute walks, four per phone profile; trains four
# networks twice) and the real cross-phone test on UJI (train A5 + BQ, test S6).
FUSED_SESSIONS = s012_mate-20-pro_pedestrian,s023_pixel-3axl_pedestrian,s039_mi-9_pedestrian,s044_honor-view-20_pedestrian
crossphone-tables: $(STAMP)
	$(BIN)/blenav-sim sim=campus_floor seed=3 out=data/campus_crossphone duration_s=600 sessions=60 \
	    'sim.carriers=[pedestrian]' sim.unlabelled_every=0 overwrite=true progress=false
	$(BIN)/blenav-eval experiment=crossphone_003 data=data/campus_crossphone out=data/results/crossphone_003 progress=false
	$(BIN)/blenav-eval experiment=crossphone_003 data=data/campus_crossphone out=data/results/crossphone_003_lr1e-3 \
	    progress=false plots=false '~experiment.baselines' experiment.learned.locnet.model.lr=1e-3 \
	    experiment.learned.transnet_locnet.model.lr=1e-3 experiment.learned.semi.model.lr=1e-3 \
	    experiment.learned.dlrnn.model.lr=1e-3
	$(BIN)/python export.py ckpt=data/results/crossphone_003_lr1e-3/runs/transnet_locnet/last.ckpt out=data/runs/campus_tl.onnx
	$(BIN)/blenav-fixes data/campus_crossphone data/runs/campus_tl.onnx --sessions $(FUSED_SESSIONS)
	$(BIN)/blenav-eval experiment=fused_003 data=data/campus_crossphone sessions=$(FUSED_SESSIONS) runs=20 \
	    out=data/results/fused_003 progress=false
	test -e data/uji_ble/dataset.yaml || $(BIN)/blenav-import uji_ble ../shared/data/raw/uji_ble data/uji_ble
	$(BIN)/blenav-eval experiment=crossphone_uji data=data/uji_ble out=data/results/crossphone_uji progress=false

realism: $(STAMP)
	$(BIN)/python benchmarks/sim_realism.py --out docs/sim_realism.md

clean-demo:
	rm -rf $(DEMO)
