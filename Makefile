# blenav: `make demo` runs the main job on the built-in default, `make test` runs the test suite.
# Both create .venv when it is missing. torch is pinned to the CPU wheel before the package installs,
# so pip never pulls a CUDA build (pyproject only asks torch>=2.13).
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
STAMP   = $(VENV)/.blenav-installed
DEMO   ?= data/demo

.PHONY: install demo test test-slow test-all bench realism feng-tables paper-tables crossphone-tables crossphone-sweep mapprior-tables mapprior-planerr selfcal-tables crf-tables backend-tables backend-robust backend-robust-lio backend-robust-vars mapping-curve realwalks-tables inertial-tables regression-check clean-demo

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e '.[dev]'
	@touch $(STAMP)

install: $(STAMP)

# The whole loop, CPU-sized (2 min 24 s from a fresh clone; README "Quick start"): simulate an office walked by DEMO_SESSIONS
# phones; train TransNet+LocNet from its Hydra config with Lightning on all walks but the last DEMO_TEST; export the
# runtime bundle (ONNX, ORT, int8); run it torch-free on the first held-out walk (a phone it never saw); write the
# network's fixes for the held-out walks; the leaderboard of learned vs classical methods on them, with the PCRLB.
# Full size: make demo DEMO_SESSIONS=16 DEMO_DURATION=384 DEMO_STEPS=6000 DEMO_RUNS=20
DEMO_SESSIONS ?= 8
DEMO_TEST     ?= 2
DEMO_DURATION ?= 150
DEMO_STEPS    ?= 3000
DEMO_RUNS     ?= 3
demo: $(STAMP)
	$(BIN)/blenav sim sim=office_45x55 seed=0 out=$(DEMO)/dataset duration_s=$(DEMO_DURATION) sessions=$(DEMO_SESSIONS) \
	    'sim.carriers=[pedestrian]' overwrite=true
	$(BIN)/blenav validate $(DEMO)/dataset
	$(BIN)/blenav plot $(DEMO)/dataset --out $(DEMO)/report
	set -e; S="$$(ls $(DEMO)/dataset/sessions)"; N=$$(echo $$S | wc -w); K=$$((N - $(DEMO_TEST))); \
	TRAIN=$$(echo $$S | cut -d' ' -f1-$$K | tr ' ' ,); TEST=$$(echo $$S | cut -d' ' -f$$((K + 1))-$$N | tr ' ' ,); \
	rm -rf $(DEMO)/run $(DEMO)/bundle; \
	$(BIN)/blenav train model=transnet_locnet data=$(DEMO)/dataset out=$(DEMO)/run "data.sessions=[$$TRAIN]" \
	    trainer.budget.max_steps=$(DEMO_STEPS); \
	$(BIN)/blenav export bundle=true ckpt=$(DEMO)/run/last.ckpt out=$(DEMO)/bundle eval_sessions=1; \
	$(BIN)/blenav localize $(DEMO)/bundle $(DEMO)/dataset/sessions/$${TEST%%,*} --out $(DEMO)/report/bundle_$${TEST%%,*}.csv; \
	$(BIN)/blenav fixes $(DEMO)/dataset $(DEMO)/bundle/localizer.onnx --sessions $$TEST; \
	$(BIN)/blenav eval overwrite=true experiment=leaderboard data=$(DEMO)/dataset runs=$(DEMO_RUNS) "sessions=[$$TEST]" \
	    "split={train: [$$TRAIN]}" out=$(DEMO)/report/leaderboard
	@echo "demo report: $(DEMO)/report (dataset plots; run/: training report and learning curves; bundle/: the app's"
	@echo "  models; bundle_*.csv: the torch-free track; leaderboard/: results.md, leaderboard_cdf.png, trajectories)"
	@echo "open in a browser (works offline): $(DEMO)/report/leaderboard/report.html"

# the default suite on TEST_WORKERS processes (pytest-xdist, tests dealt as workers free up): under 10 min
# on this 2-core machine (README "Quick start"); TEST_WORKERS=0 runs it in one process
TEST_WORKERS ?= 2
test: $(STAMP)
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist worksteal

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -m "" -n $(TEST_WORKERS) --dist worksteal

bench: $(STAMP)
	$(BIN)/python benchmarks/sim_speed.py
	$(BIN)/python benchmarks/filter_speed.py
	$(BIN)/python benchmarks/backend_speed.py
	$(BIN)/python benchmarks/backend_offset.py
	$(BIN)/python benchmarks/stream_flat.py
	$(BIN)/python benchmarks/map_index.py
	$(BIN)/python benchmarks/onnx_speed.py
	$(BIN)/python benchmarks/runtime_latency.py
	$(BIN)/python benchmarks/soak.py
	$(BIN)/python benchmarks/crossphone_train.py
	$(BIN)/python benchmarks/mapprior_train.py
	$(BIN)/python benchmarks/ilc20_import.py
	$(BIN)/python benchmarks/crf_speed.py

# The README's result tables: per preset, 5 sessions of 384 s with one phone model (as the papers), the
# first walk calibrates the path-loss model and is not scored, then both experiments with 100 runs.
PRESETS ?= office_45x55 campus_floor
paper-tables: $(STAMP)
	for P in $(PRESETS); do \
	  $(BIN)/blenav-sim sim=$$P seed=1 out=data/$${P}_eval duration_s=384 sessions=5 'sim.receivers=[iphone-8]' \
	      'sim.carriers=[pedestrian,pedestrian,robot,pedestrian,robot]' sim.unlabelled_every=0 overwrite=true progress=false && \
	  CAL=$$(ls data/$${P}_eval/sessions | head -1) && \
	  $(BIN)/blenav-eval overwrite=true experiment=mapfusion_002 data=data/$${P}_eval runs=100 calibration=[$$CAL] \
	      out=data/results/$${P}_mapfusion_002 progress=false && \
	  $(BIN)/blenav-eval overwrite=true experiment=frontend_000 data=data/$${P}_eval runs=100 calibration=[$$CAL] \
	      out=data/results/$${P}_frontend_000 progress=false || exit 1; \
	done

# Roy's Tables 3.3-3.5 on the simulated campus (60 ten-minute walks, four per phone profile; trains four
# networks twice) and the real cross-phone test on UJI (train A5 + BQ, test S6).
FUSED_SESSIONS = s012_mate-20-pro_pedestrian,s023_pixel-3axl_pedestrian,s039_mi-9_pedestrian,s044_honor-view-20_pedestrian
# Roy's training recipe (Adam lr 1e-4, 50 epochs, then 20 semi-supervised epochs at 1e-5) under the step-budget
# trainer: no step cap, no early stopping, constant lr (the default is the budget of conf/trainer/cpu.yaml)
THESIS_RECIPE = experiment.learned.locnet.model.lr=1e-4 experiment.learned.locnet_aug.model.lr=1e-4 \
    experiment.learned.transnet_locnet.model.lr=1e-4 experiment.learned.semi.model.lr=1e-4 \
    experiment.learned.dlrnn.model.lr=1e-4 trainer.max_epochs=50 trainer.budget.max_steps=-1 \
    trainer.budget.patience=null trainer.budget.schedule=constant trainer.budget.warmup_steps=0 \
    experiment.learned.semi.semi.epochs=20 experiment.learned.semi.semi.lr=1e-5 data.batch_size=256
# issue 16: the smallest simulated survey at which TransNet+LocNet overtakes KNN (walks of 15/30/60/240 s, two
# seeds; one TransNet+LocNet training per point, heavy: docs/results-003-crossphone.md)
crossphone-sweep: $(STAMP)
	nice -n 10 $(BIN)/python benchmarks/crossphone_sweep.py --seeds 16,17 --durations 15,30,60,240

crossphone-tables: $(STAMP)
	$(BIN)/blenav-sim sim=campus_floor seed=3 out=data/campus_crossphone duration_s=600 sessions=60 \
	    'sim.carriers=[pedestrian]' sim.unlabelled_every=0 overwrite=true progress=false
	$(BIN)/blenav-eval overwrite=true experiment=crossphone_003 data=data/campus_crossphone out=data/results/crossphone_003 progress=false
	$(BIN)/blenav-eval overwrite=true experiment=crossphone_003 data=data/campus_crossphone out=data/results/crossphone_003_thesis \
	    progress=false plots=false '~experiment.baselines' $(THESIS_RECIPE)
	$(BIN)/python export.py ckpt=data/results/crossphone_003/runs/transnet_locnet/last.ckpt out=data/runs/campus_tl.onnx
	$(BIN)/blenav-fixes data/campus_crossphone data/runs/campus_tl.onnx --sessions $(FUSED_SESSIONS)
	$(BIN)/blenav-eval overwrite=true experiment=fused_003 data=data/campus_crossphone sessions=$(FUSED_SESSIONS) runs=20 \
	    out=data/results/fused_003 progress=false
	test -e data/uji_ble/dataset.yaml || $(BIN)/blenav-import uji_ble ../shared/data/raw/uji_ble data/uji_ble
	$(BIN)/blenav-eval overwrite=true experiment=crossphone_uji data=data/uji_ble out=data/results/crossphone_uji progress=false
	$(BIN)/blenav-eval overwrite=true experiment=crossphone_uji data=data/uji_ble out=data/results/crossphone_uji_noaug progress=false \
	    plots=false experiment.learned.transnet_locnet.model.augment.offset_db_std=0 \
	    experiment.learned.transnet_locnet.model.augment.gain_std=0 experiment.learned.transnet_locnet.model.augment.dropout_max=0

# Roy's Tables 3.7 / 3.6 on two procedural buildings the map prior never saw (procedural_006, _007), with
# learned BLE fixes as the thesis (its per-building BLE model): 64 survey walks of the same 8 buildings
# (sessions s032..s095 of the same seed, so none repeats a test walk), per held-out building a dense
# TransNet+LocNet (all beacons) and a sparse one (data.beacons=4: the 4 beacons the eval's
# fixes.sparse_beacons picks), their fixes written into the test walks (sources locnet-dense /
# locnet-sparse4), then both experiments. Builds procedural_mp and the map prior only when absent.
# Model type (TransNet+LocNet over LocNet) and 200 epochs were chosen on building 000 (README, map prior).
MP_SIM = sim=procedural seed=4 duration_s=300 'sim.carriers=[pedestrian]' sim.unlabelled_every=0 \
    sim.odometry.drift_deg_per_min_std=6 sim.odometry.heading_rw_deg=0.8 sim.odometry.scale_std=0.1
# IDOL-level odometry (ours): an AR(1) velocity error of 0.3 m/s with a 3 s correlation time on top of
# MP_SIM's scale and heading errors; odometry alone then drifts 8 m ATE over 300 s (the thesis: 4.5-9.9 m)
MP_IO_NOISE = sim.odometry.vel_noise_mps=0.3 sim.odometry.vel_noise_tau_s=3
MP_TEST_006 = s006_pixel-4xl_pedestrian,s014_honor-view-20_pedestrian,s022_pixel-3xl_pedestrian,s030_iphone-7_pedestrian
MP_TEST_007 = s007_pixel-3xl_pedestrian,s015_iphone-7_pedestrian,s023_pixel-3axl_pedestrian,s031_iphone-8_pedestrian
MP_FIX_TRAIN = experiment=crossphone_s1 model=transnet_locnet data.holdout=0 \
    model.lr=1e-3 trainer.max_epochs=$(MP_FIX_EPOCHS) threads=1 trainer.enable_progress_bar=false \
    trainer.budget.max_steps=-1 trainer.budget.patience=null trainer.budget.schedule=constant trainer.budget.warmup_steps=0
MP_FIX_EPOCHS ?= 200
MP_TEST_A = s006_pixel-4xl_pedestrian,s007_pixel-3xl_pedestrian,s014_honor-view-20_pedestrian,s015_iphone-7_pedestrian
MP_TEST_B = s022_pixel-3xl_pedestrian,s023_pixel-3axl_pedestrian,s030_iphone-7_pedestrian,s031_iphone-8_pedestrian
# the same 8 walks as MP_TEST_006/007, in the order the tables were measured (each walk's run seeds follow
# its position in sessions=)
MP_TEST = $(MP_TEST_A),$(MP_TEST_B)
MP_LG_SIM = sim=procedural sim.name=procedural_large sim.buildings=2 sim.layout.width_m=60 sim.layout.height_m=40 \
    sim.layout.n_h=3 sim.layout.n_v=2 sim.n_beacons=22 seed=5 duration_s=300 'sim.carriers=[pedestrian]' \
    sim.unlabelled_every=0 sim.odometry.drift_deg_per_min_std=6 sim.odometry.heading_rw_deg=0.8 sim.odometry.scale_std=0.1
MP_LG_000 = s000_iphone-7_pedestrian,s002_iphone-xr_pedestrian,s004_galaxy-note9_pedestrian,s006_pixel-4xl_pedestrian
MP_LG_001 = s001_iphone-8_pedestrian,s003_galaxy-s10_pedestrian,s005_galaxy-a50_pedestrian,s007_pixel-3xl_pedestrian
MP_CALIB = s000_iphone-7_pedestrian,s008_pixel-3axl_pedestrian,s016_iphone-8_pedestrian,s024_mi-9_pedestrian
MP_LONG_006 = s102_mate-20-pro_pedestrian,s110_galaxy-a50_pedestrian,s118_honor-20-pro_pedestrian,s126_pixel-4xl_pedestrian
MP_LONG_007 = s103_honor-20-pro_pedestrian,s111_pixel-4xl_pedestrian,s119_honor-view-20_pedestrian,s127_pixel-3xl_pedestrian
# the sparse models' 4 beacons must be the ones the eval's fixes.sparse_beacons: 4 picks (spread_beacons)
MP_CHECK_SPARSE = from blenav.data import Dataset; from blenav.runtime import OnnxLocalizer; \
    from blenav.features.windows import spread_beacons; ds = Dataset.open(D); \
    s = [x for x in ds.sessions() if x.building.id == 'procedural_' + B][0]; \
    m = OnnxLocalizer('data/runs/mapprior_fix/sparse4_%s.onnx' % B, building=s.building); \
    e = sorted(spread_beacons(s.building.anchors, 4, s.meta.get('floor'), s.floor)); \
    assert m.beacons == e, (m.beacons, e); print('procedural_%s: sparse model beacons %s = the eval choice' % (B, e))
mapprior-tables: $(STAMP)
	test -e data/procedural_mp/dataset.yaml || $(BIN)/blenav-sim $(MP_SIM) out=data/procedural_mp sessions=32 progress=false
	test -e data/runs/mapprior_proc_onnx/meta.json || { \
	  $(BIN)/python train.py experiment=mapprior data=data/procedural_mp out=data/runs/mapprior_proc \
	      'data.val_buildings=[procedural_006,procedural_007]' trainer.max_epochs=20 && \
	  $(BIN)/python export.py ckpt=data/runs/mapprior_proc/last.ckpt out=data/runs/mapprior_proc_onnx; }
	$(BIN)/blenav-sim $(MP_SIM) first_session=32 sessions=64 out=data/procedural_mp_survey overwrite=true progress=false
	diff -r data/procedural_mp/buildings data/procedural_mp_survey/buildings
	for B in 006 007; do \
	  rm -rf data/runs/mapprior_fix/dense_$$B data/runs/mapprior_fix/sparse4_$$B && \
	  $(BIN)/python train.py $(MP_FIX_TRAIN) data=data/procedural_mp_survey data.building=procedural_$$B out=data/runs/mapprior_fix/dense_$$B && \
	  $(BIN)/python train.py $(MP_FIX_TRAIN) data=data/procedural_mp_survey data.building=procedural_$$B data.beacons=4 \
	      out=data/runs/mapprior_fix/sparse4_$$B && \
	  $(BIN)/python export.py ckpt=data/runs/mapprior_fix/dense_$$B/last.ckpt out=data/runs/mapprior_fix/dense_$$B.onnx && \
	  $(BIN)/python export.py ckpt=data/runs/mapprior_fix/sparse4_$$B/last.ckpt out=data/runs/mapprior_fix/sparse4_$$B.onnx && \
	  $(BIN)/python -c "B = '$$B'; D = 'data/procedural_mp'; $(MP_CHECK_SPARSE)" || exit 1; \
	done
	# the same 8 test walks with odometry as noisy as a learned inertial odometry (IDOL-level; ours, see the
	# README): only odometry.csv differs from data/procedural_mp (checked below)
	$(BIN)/blenav-sim $(MP_SIM) $(MP_IO_NOISE) sessions=32 out=data/procedural_mp_io overwrite=true progress=false
	for S in $$(echo $(MP_TEST) | tr , ' '); do for F in groundtruth.csv rssi.csv; do \
	  cmp data/procedural_mp/sessions/$$S/$$F data/procedural_mp_io/sessions/$$S/$$F || exit 1; done; done
	for D in procedural_mp procedural_mp_io; do for K in dense:locnet-dense sparse4:locnet-sparse4; do \
	  $(BIN)/blenav-fixes data/$$D data/runs/mapprior_fix/$${K%%:*}_006.onnx --source $${K##*:} --sessions $(MP_TEST_006) && \
	  $(BIN)/blenav-fixes data/$$D data/runs/mapprior_fix/$${K%%:*}_007.onnx --source $${K##*:} --sessions $(MP_TEST_007) || exit 1; \
	done; done
	$(BIN)/blenav-eval overwrite=true experiment=mapprior_003_table37 data=data/procedural_mp sessions=$(MP_TEST) \
	    runs=3 model_path=data/runs/mapprior_proc_onnx fixes.dense=locnet-dense fixes.sparse=locnet-sparse4 \
	    out=data/results/mapprior_table37_learnedfix progress=false
	$(BIN)/blenav-eval overwrite=true experiment=mapprior_003_table36 data=data/procedural_mp sessions=$(MP_TEST) \
	    runs=3 model_path=data/runs/mapprior_proc_onnx out=data/results/mapprior_table36 progress=false
	$(BIN)/blenav-eval overwrite=true experiment=mapprior_003_table37 data=data/procedural_mp_io sessions=$(MP_TEST) \
	    runs=3 model_path=data/runs/mapprior_proc_onnx fixes.dense=locnet-dense fixes.sparse=locnet-sparse4 \
	    out=data/results/mapprior_table37_io progress=false
	$(BIN)/blenav-eval overwrite=true experiment=mapprior_003_table36 data=data/procedural_mp_io sessions=$(MP_TEST) \
	    runs=3 model_path=data/runs/mapprior_proc_onnx out=data/results/mapprior_table36_io progress=false
	# 15-min walks in the same two buildings (more odometry drift, nearer the thesis' IO error), same models
	$(BIN)/blenav-sim $(MP_SIM) duration_s=900 first_session=96 sessions=32 out=data/procedural_mp_long overwrite=true progress=false
	diff -r data/procedural_mp/buildings data/procedural_mp_long/buildings
	for K in dense:locnet-dense sparse4:locnet-sparse4; do \
	  $(BIN)/blenav-fixes data/procedural_mp_long data/runs/mapprior_fix/$${K%%:*}_006.onnx --source $${K##*:} --sessions $(MP_LONG_006) && \
	  $(BIN)/blenav-fixes data/procedural_mp_long data/runs/mapprior_fix/$${K%%:*}_007.onnx --source $${K##*:} --sessions $(MP_LONG_007) || exit 1; \
	done
	$(BIN)/blenav-eval overwrite=true experiment=mapprior_003_table37 data=data/procedural_mp_long sessions=$(MP_LONG_006),$(MP_LONG_007) \
	    runs=3 model_path=data/runs/mapprior_proc_onnx fixes.dense=locnet-dense fixes.sparse=locnet-sparse4 \
	    out=data/results/mapprior_table37_long progress=false
	# calibrated fix likelihood (ours): a sparse model trained the same way for building 000 (not a test
	# building), its fixes' error statistics on building 000's walks -> sigma_eff for the sparse rows
	rm -rf data/runs/mp_calib/sparse4_000
	$(BIN)/python train.py $(MP_FIX_TRAIN) data=data/procedural_mp_survey data.building=procedural_000 data.beacons=4 out=data/runs/mp_calib/sparse4_000
	$(BIN)/python export.py ckpt=data/runs/mp_calib/sparse4_000/last.ckpt out=data/runs/mp_calib/sparse4_000.onnx
	SIG=$$($(BIN)/blenav-fixes data/procedural_mp data/runs/mp_calib/sparse4_000.onnx --calibrate \
	      --sessions $(MP_CALIB) | tail -n 1 | cut -d= -f2) && test -n "$$SIG" && echo "sparse fixes: sigma_eff $$SIG m" && \
	for W in procedural_mp:$(MP_TEST):calibrated procedural_mp_io:$(MP_TEST):io_calibrated procedural_mp_long:$(MP_LONG_006),$(MP_LONG_007):long_calibrated; do \
	  $(BIN)/blenav-eval overwrite=true experiment=mapprior_003_table37 data=data/$${W%%:*} sessions=$$(echo $$W | cut -d: -f2) \
	      runs=3 model_path=data/runs/mapprior_proc_onnx fixes.dense=locnet-dense fixes.sparse=locnet-sparse4 \
	      methods.sparse_io.measurements.fix.sigma_m=$$SIG methods.sparse_io_map.measurements.fix.sigma_m=$$SIG \
	      out=data/results/mapprior_table37_$${W##*:} progress=false && \
	  $(BIN)/blenav-eval overwrite=true experiment=mapprior_003_table37 data=data/$${W%%:*} sessions=$$(echo $$W | cut -d: -f2) \
	      runs=3 model_path=data/runs/mapprior_proc_onnx fixes.dense=locnet-dense fixes.sparse=locnet-sparse4 \
	      methods.sparse_io.measurements.fix.sigma_m=$$SIG methods.sparse_io_map.measurements.fix.sigma_m=$$SIG \
	      methods.sparse_io.map.init=groundtruth methods.sparse_io_map.map.init=groundtruth \
	      out=data/results/mapprior_table37_$${W##*:}_gtstart progress=false || exit 1; \
	done
	# the same prior trained on to at most 80 epochs (early stopping; a resumed run draws the same samples
	# per epoch as an uninterrupted one), on both walk sets
	test -e data/runs/mapprior_proc80_onnx/meta.json || { rm -rf data/runs/mapprior_proc80 && \
	  mkdir -p data/runs/mapprior_proc80 && cp data/runs/mapprior_proc/last.ckpt data/runs/mapprior_proc80/ && \
	  $(BIN)/python train.py experiment=mapprior data=data/procedural_mp out=data/runs/mapprior_proc80 \
	    'data.val_buildings=[procedural_006,procedural_007]' trainer.max_epochs=80 trainer.enable_progress_bar=false && \
	  $(BIN)/python export.py ckpt=data/runs/mapprior_proc80/last.ckpt out=data/runs/mapprior_proc80_onnx; }
	$(BIN)/blenav-eval overwrite=true experiment=mapprior_003_table37 data=data/procedural_mp sessions=$(MP_TEST) \
	    runs=3 model_path=data/runs/mapprior_proc80_onnx fixes.dense=locnet-dense fixes.sparse=locnet-sparse4 \
	    out=data/results/mapprior_table37_e80 progress=false
	$(BIN)/blenav-eval overwrite=true experiment=mapprior_003_table37 data=data/procedural_mp_long sessions=$(MP_LONG_006),$(MP_LONG_007) \
	    runs=3 model_path=data/runs/mapprior_proc80_onnx fixes.dense=locnet-dense fixes.sparse=locnet-sparse4 \
	    out=data/results/mapprior_table37_long_e80 progress=false
	# two larger buildings (60 x 40 m, 22 beacons as the thesis' dense set), unlike any the prior saw: 8 test
	# walks with MP_SIM's odometry and the same walks with IDOL-level odometry, 16 survey walks for the
	# per-building dense and sparse fix models (trained as above), the same 20-epoch prior
	$(BIN)/blenav-sim $(MP_LG_SIM) sessions=8 out=data/procedural_large overwrite=true progress=false
	$(BIN)/blenav-sim $(MP_LG_SIM) $(MP_IO_NOISE) sessions=8 out=data/procedural_large_io overwrite=true progress=false
	$(BIN)/blenav-sim $(MP_LG_SIM) first_session=8 sessions=16 out=data/procedural_large_survey overwrite=true progress=false
	diff -r data/procedural_large/buildings data/procedural_large_survey/buildings
	for BS in 000:$(MP_LG_000) 001:$(MP_LG_001); do B=$${BS%%:*}; \
	  rm -rf data/runs/mapprior_fix/dense_large_$$B data/runs/mapprior_fix/sparse4_large_$$B && \
	  $(BIN)/python train.py $(MP_FIX_TRAIN) data=data/procedural_large_survey data.building=procedural_large_$$B \
	      out=data/runs/mapprior_fix/dense_large_$$B && \
	  $(BIN)/python train.py $(MP_FIX_TRAIN) data=data/procedural_large_survey data.building=procedural_large_$$B \
	      data.beacons=4 out=data/runs/mapprior_fix/sparse4_large_$$B && \
	  for K in dense sparse4; do \
	    $(BIN)/python export.py ckpt=data/runs/mapprior_fix/$${K}_large_$$B/last.ckpt \
	        out=data/runs/mapprior_fix/$${K}_large_$$B.onnx || exit 1; \
	  done && \
	  $(BIN)/python -c "B = 'large_$$B'; D = 'data/procedural_large'; $(MP_CHECK_SPARSE)" && \
	  for K in dense sparse4; do \
	    for D in procedural_large procedural_large_io; do \
	      $(BIN)/blenav-fixes data/$$D data/runs/mapprior_fix/$${K}_large_$$B.onnx --source locnet-$$K \
	          --sessions $${BS#*:} || exit 1; \
	    done; \
	  done || exit 1; \
	done
	for D in procedural_large procedural_large_io; do \
	  $(BIN)/blenav-eval overwrite=true experiment=mapprior_003_table37 data=data/$$D runs=3 model_path=data/runs/mapprior_proc_onnx \
	      fixes.dense=locnet-dense fixes.sparse=locnet-sparse4 out=data/results/mapprior_table37_$${D#procedural_} \
	      progress=false || exit 1; \
	done

# Wrong floor plans (ours, not the thesis'): Table 3.6 on the same 8 test walks, smooth and IDOL-level
# odometry, when the plan the filters get has K spurious barriers per 100 m^2 of free space across doorways
# and narrow passages, or is registered MP_PLANOFF m off in x (blenav.eval.plan_errors); uses the prior and
# walks of `make mapprior-tables`
MP_PLANERR ?= 1 2
MP_PLANOFF ?= 0.5
mapprior-planerr: $(STAMP)
	@test -e data/runs/mapprior_proc_onnx/meta.json -a -e data/procedural_mp_io/dataset.yaml || \
	  { echo "mapprior-planerr: run 'make mapprior-tables' first (it trains the prior and simulates the walks)"; exit 1; }
	for P in $(foreach K,$(MP_PLANERR),'planerr$(K):plan_error.barriers_per_100m2=$(K)') \
	    'planoff:plan_error.offset_m=[$(MP_PLANOFF),0]'; do for D in procedural_mp procedural_mp_io; do \
	  $(BIN)/blenav-eval overwrite=true experiment=mapprior_003_table36 data=data/$$D sessions=$(MP_TEST) runs=3 \
	      model_path=data/runs/mapprior_proc_onnx "$${P#*:}" \
	      out=data/results/mapprior_table36_$${D#procedural_}_$${P%%:*} progress=false || exit 1; \
	done; done

# Receivers that calibrate themselves (issue 14 sec. 4): the mixed-phone office of the README (five phones,
# path loss fitted on the iPhone 7 walk), mapfusion_002 with PF-PL+offset and PF-PS+MAP+offset, against
# PF-PS+MAP calibrated on each test walk itself (the best a per-phone calibration can do)
SELFCAL_RUNS ?= 30
selfcal-tables: $(STAMP)
	test -e data/office_mixed/dataset.yaml || $(BIN)/blenav-sim sim=office_45x55 seed=1 out=data/office_mixed \
	    duration_s=384 sessions=5 'sim.carriers=[pedestrian,pedestrian,robot,pedestrian,robot]' progress=false
	$(BIN)/blenav-eval overwrite=true experiment=mapfusion_002 data=data/office_mixed runs=$(SELFCAL_RUNS) \
	    calibration=[s000_iphone-7_pedestrian] out=data/results/office_mixed_selfcal progress=false plots=false
	for S in $$(ls data/office_mixed/sessions | tail -n +2); do \
	  $(BIN)/blenav-eval overwrite=true experiment=mapfusion_002 data=data/office_mixed runs=$(SELFCAL_RUNS) sessions=$$S \
	      calibration=[$$S] methods.pf_pl=null methods.pf_pl_map=null methods.pf_ps=null methods.pf_pl_offset=null \
	      methods.pf_ps_map_offset=null out=data/results/office_mixed_owncal/$$S progress=false plots=false || exit 1; \
	done
	cp data/results/office_mixed_selfcal/results.md docs/results/office_mixed_selfcal_mapfusion_002.md
	$(BIN)/python -m blenav.cli.tables merge docs/results/office_mixed_selfcal.md \
	    "Self-calibrating receivers on the mixed-phone office (calibrated on the iPhone 7 walk)" \
	    data/results/office_mixed_selfcal $$(ls -d data/results/office_mixed_owncal/*/ | sed 's|/$$|:own-calibration/|')

# The back-end of Ghaffari Jadidi et al. (issue 14): Fig. 3 (accurate map) and Figs. 4-5 (map perturbed by 3 m per
# axis) on one simulated 384 s office walk, BACKEND_RUNS runs (every perturbed run loops the back-end: ~1 min each)
BACKEND_RUNS ?= 5
BACKEND_DATA ?= data/sim/office_backend
backend-tables: $(STAMP)
	test -e $(BACKEND_DATA)/dataset.yaml || $(BIN)/blenav-sim sim=office_45x55 seed=0 out=$(BACKEND_DATA) \
	    duration_s=384 sessions=1 progress=false
	$(BIN)/blenav-eval overwrite=true experiment=backend_000 data=$(BACKEND_DATA) runs=$(BACKEND_RUNS) out=data/results/backend_000 \
	    progress=false
	$(BIN)/blenav-eval overwrite=true experiment=mapnoise_000 data=$(BACKEND_DATA) runs=$(BACKEND_RUNS) out=data/results/mapnoise_000 \
	    progress=false
	cp data/results/backend_000/results.md docs/results/office_backend_000.md
	cp data/results/mapnoise_000/results.md docs/results/office_mapnoise_000.md

# Beacon maps from walks (issue 14, sec. 3): blenav-map's error against walking time on 4 simulated 480 s walks
# (four phones) in the office, cut to their first T minutes in total (~2 min of compute)
MAPPING_DATA ?= data/sim/office_mapping
mapping-curve: $(STAMP)
	test -e $(MAPPING_DATA)/dataset.yaml || $(BIN)/blenav-sim sim=office_45x55 seed=2 out=$(MAPPING_DATA) duration_s=480 \
	    sessions=4 progress=false 'sim.carriers=[pedestrian]'
	$(BIN)/python benchmarks/mapping_curve.py $(MAPPING_DATA) --minutes 1,2,4,8,16,32 --out docs/results/mapping_vs_time.md

# The CRF of Duembgen et al. (issue 15): Table I and Fig. 11-12 on simulated crf_004 walks (6 walks of 300 s
# and 2 static surveys for offline calibration; tuning was done on seed 0, these are seed 1)
CRF_DATA ?= data/sim/crf_004
crf-tables: $(STAMP)
	test -e $(CRF_DATA)/dataset.yaml || $(BIN)/blenav-sim sim=crf_004 seed=1 out=$(CRF_DATA) duration_s=300 \
	    sessions=8 progress=false
	$(BIN)/blenav-eval overwrite=true experiment=crf_004_table1 data=$(CRF_DATA) out=data/results/crf_004_table1 progress=false
	$(BIN)/blenav-eval overwrite=true experiment=crf_004_fig12 data=$(CRF_DATA) out=data/results/crf_004_fig12 progress=false
	$(BIN)/python -m blenav.cli.tables crf data/results/crf_004_table1 data/results/crf_004_fig12 \
	    docs/results/crf_004_tables.md

# Issue 18 sec. 2: the leaderboard -- every method of the project and the PCRLB -- over a fleet of datasets as one
# Hydra multirun (joblib launcher, LB_JOBS datasets at a time), merged into LB_OUT/fleet.md: a simulated office with
# non-default names (LB_SIM, simulated when missing) and LB_REAL, e.g. an imported ILC dataset (optional; the PCRLB is
# skipped there). LB_RUNS runs per session and method; LB_ARGS more overrides (model_path=DIR, '+split={...}').
# docs/results-leaderboard.md
LB_OUT ?= data/results/leaderboard
LB_SIM ?= data/sim/leaderboard_wharf
LB_REAL ?=
LB_RUNS ?= 10
LB_JOBS ?= 1
LB_ARGS ?=
lb_comma := ,
leaderboard: $(STAMP)
	test -e $(LB_SIM)/dataset.yaml || $(BIN)/blenav-sim sim=small sim.name=wharf_lab \
	    'sim.receivers=[honor-20-pro,redmi-note8]' seed=2 out=$(LB_SIM) duration_s=120 sessions=2 progress=false
	$(BIN)/blenav-eval -m overwrite=true experiment=leaderboard data=$(LB_SIM)$(if $(LB_REAL),$(lb_comma)$(LB_REAL)) runs=$(LB_RUNS) \
	    'out=$(LB_OUT)/$${hydra:job.num}' hydra/launcher=joblib hydra.launcher.n_jobs=$(LB_JOBS) \
	    hydra.sweep.dir=$(LB_OUT)/.multirun progress=false $(LB_ARGS)
	$(BIN)/python -m blenav.cli.tables leaderboard $(LB_OUT)/fleet.md "Leaderboard over the fleet (make leaderboard)" \
	    $(LB_OUT)

# Issue 32: the back-end on buildings and channels it was not tuned to. Three simulated buildings, each with a BLE
# channel other than the presets' (stronger walls and body shadowing, other exponents and shadowing), 2 walks of
# 240 s; an office annex walked 7 x 240 s by six phones of brands the other sets do not use, on another channel
# (like the check from outside of issue 32); the campus floor's channel walked 7 x 240 s (6 labelled); and the 384 s
# office of backend-tables; on each backend_000 (true map) and mapnoise_pooled (mapnoise_000, every beacon moved by
# N(0, 3^2) m, with one draw per run for every walk), BR_RUNS runs, the IMU filter, F-end and B-end, and on the wrong
# map F-end+pool / B-end+pool (BR_POOL: the map pooled from every walk, blenav.backend.pooled);
# docs/results/backend_robust.md (35 min).
BR_RUNS ?= 5
BR_ARGS ?=
BR_DATA ?= data/sim/backend_robust
BR_OUT  ?= data/results/backend_robust
BR_DOC  ?= docs/results/backend_robust.md
BR_TITLE ?= The back-end on buildings and channels it was not tuned to (make backend-robust, $(BR_RUNS) runs)
BR_CMD  ?= make backend-robust
BR_POOL ?= ,F-end+pool,B-end+pool
BR_NOISE ?= mapnoise_pooled
BR_EVAL  = $(BIN)/blenav eval overwrite=true runs=$(BR_RUNS) progress=false plots=false report=false
backend-robust: $(STAMP)
	test -e $(BR_DATA)/office_ch/dataset.yaml || $(BIN)/blenav sim sim=office_45x55 seed=5 out=$(BR_DATA)/office_ch \
	    duration_s=240 sessions=2 progress=false 'sim.carriers=[pedestrian]' sim.ble.wall_db=7 sim.ble.body_db=10 \
	    sim.ble.path_loss_exponent=2.6 sim.ble.shadow_std_db=5
	test -e $(BR_DATA)/campus_ch/dataset.yaml || $(BIN)/blenav sim sim=campus_floor seed=6 out=$(BR_DATA)/campus_ch \
	    duration_s=240 sessions=2 progress=false 'sim.carriers=[pedestrian]' sim.ble.wall_db=6 sim.ble.body_db=8 \
	    sim.ble.path_loss_exponent=2.4
	test -e $(BR_DATA)/proc_ch/dataset.yaml || $(BIN)/blenav sim sim=procedural seed=7 out=$(BR_DATA)/proc_ch \
	    duration_s=240 sessions=2 progress=false 'sim.carriers=[pedestrian]' sim.ble.wall_db=5 sim.ble.shadow_std_db=6 \
	    sim.ble.path_loss_exponent=2.0
	test -e $(BR_DATA)/annex/dataset.yaml || $(BIN)/blenav sim sim=office_45x55 sim.name=annex_offices seed=21 \
	    out=$(BR_DATA)/annex duration_s=240 sessions=7 progress=false 'sim.carriers=[pedestrian]' \
	    'sim.receivers=[mi-9,mi-9t-pro,mate-20-pro,honor-20-pro,honor-view-20,pixel-3axl]' sim.ble.wall_db=6 \
	    sim.ble.body_db=9 sim.ble.path_loss_exponent=2.4 sim.ble.shadow_std_db=4.5
	test -e $(BR_DATA)/campus_walks/dataset.yaml || $(BIN)/blenav sim sim=campus_floor seed=6 \
	    out=$(BR_DATA)/campus_walks duration_s=240 sessions=7 progress=false 'sim.carriers=[pedestrian]' \
	    sim.ble.wall_db=6 sim.ble.body_db=8 sim.ble.path_loss_exponent=2.4
	test -e $(BACKEND_DATA)/dataset.yaml || $(BIN)/blenav sim sim=office_45x55 seed=0 out=$(BACKEND_DATA) \
	    duration_s=384 sessions=1 progress=false
	set -e; for d in office_ch campus_ch proc_ch annex campus_walks office; do \
	    src=$(BR_DATA)/$$d; [ $$d = office ] && src=$(BACKEND_DATA); \
	    $(BR_EVAL) experiment=backend_000 data=$$src out=$(BR_OUT)/$$d only=IMU,F-end,B-end $(BR_ARGS); \
	    $(BR_EVAL) experiment=$(BR_NOISE) data=$$src out=$(BR_OUT)/$${d}_noise only=IMU,F-end,B-end$(BR_POOL) \
	        $(BR_ARGS); done
	$(BIN)/blenav tables backend --made-by "$(BR_CMD)" $(BR_DOC) "$(BR_TITLE)" \
	    "office 45x55, walls 7 dB, body 10 dB, exponent 2.6, shadowing 5 dB=$(BR_OUT)/office_ch,$(BR_OUT)/office_ch_noise" \
	    "campus floor, walls 6 dB, body 8 dB, exponent 2.4=$(BR_OUT)/campus_ch,$(BR_OUT)/campus_ch_noise" \
	    "procedural building, walls 5 dB, shadowing 6 dB, exponent 2.0=$(BR_OUT)/proc_ch,$(BR_OUT)/proc_ch_noise" \
	    "office annex, 7 walks by six phones of other brands, walls 6 dB, body 9 dB, exponent 2.4, shadowing 4.5 dB=$(BR_OUT)/annex,$(BR_OUT)/annex_noise" \
	    "campus floor, 7 walks (6 labelled), walls 6 dB, body 8 dB, exponent 2.4=$(BR_OUT)/campus_walks,$(BR_OUT)/campus_walks_noise" \
	    "office 45x55 of backend-tables (preset channel)=$(BR_OUT)/office,$(BR_OUT)/office_noise"

# Issue 31 in the back-end: the same runs with a learned inertial odometry's between-factors (io_model=), the model
# trained on simulated walks of another building (sim=small, 12 walks of 120 s; ~3 min), docs/results/backend_robust_lio.md
# (made with the plain network, before exports averaged it over turns of the frame: BR_YAWS=1 keeps that page's export;
# BR_YAWS= takes export.py's default)
BR_IO ?= data/runs/backend_io_onnx
BR_YAWS ?= 1
backend-robust-lio: $(STAMP)
	test -e $(BR_IO)/meta.json || { \
	  $(BIN)/blenav-sim sim=small seed=21 out=data/sim/backend_io_walks duration_s=120 sessions=12 overwrite=true \
	      progress=false 'sim.carriers=[pedestrian]' && \
	  $(BIN)/python train.py experiment=inertial data=data/sim/backend_io_walks out=data/runs/backend_io && \
	  $(BIN)/python export.py ckpt=data/runs/backend_io/last.ckpt out=$(BR_IO) $(if $(BR_YAWS),yaw_ensemble=$(BR_YAWS)); }
	$(MAKE) -o $(STAMP) backend-robust BR_ARGS=io_model=$(BR_IO) BR_POOL= BR_NOISE=mapnoise_000 \
	    BR_OUT=data/results/backend_robust_lio \
	    BR_DOC=docs/results/backend_robust_lio.md "BR_CMD=make backend-robust-lio" \
	    "BR_TITLE=The back-end with a learned inertial odometry's between-factors (make backend-robust-lio, $(BR_RUNS) runs)"

# Issue 32: the same runs with the receiver offset and the path-loss exponent as variables of the graph (F-end and
# B-end; off by default), docs/results/backend_robust_vars.md (~11 min)
BR_VARS = $(foreach m,B-end F-end,$(foreach k,estimate_offset estimate_exponent,+methods.$(m).backend.range.$(k)=true))
backend-robust-vars: $(STAMP)
	$(MAKE) -o $(STAMP) backend-robust "BR_ARGS=$(BR_VARS)" BR_POOL= BR_NOISE=mapnoise_000 \
	    BR_OUT=data/results/backend_robust_vars \
	    BR_DOC=docs/results/backend_robust_vars.md "BR_CMD=make backend-robust-vars" \
	    "BR_TITLE=The back-end with the receiver offset and the path-loss exponent as graph variables (make backend-robust-vars, $(BR_RUNS) runs)"

realism: $(STAMP)
	$(BIN)/python benchmarks/sim_realism.py --out docs/sim_realism.md

# Issue 15 sec. 3: RTT-only localization at the Feng et al. test points (real WiFi RTT), without / with offline
# calibration and the -65 dBm rule; writes docs/results/feng_rtt.md.
FENG_RAW ?= ../shared/data/raw/feng_wifi_rtt
feng-tables: $(STAMP)
	rm -rf data/feng_wifi_rtt && $(BIN)/blenav-import feng_wifi_rtt $(FENG_RAW) data/feng_wifi_rtt
	$(BIN)/blenav-eval overwrite=true experiment=crf_004_feng data=data/feng_wifi_rtt out=data/results/crf_004_feng progress=false
	$(BIN)/python -m blenav.cli.tables feng data/results/crf_004_feng/results.json docs/results/feng_rtt.md "make feng-tables"

# Issue 17 sec. 2: every method on the ILC 2.0 real walks (three floors of site1), per floor, from the raw archives:
# import, beacon map from the train walks only (blenav-map writes only the walks it maps: the full import gets its
# anchors.csv, unplaced beacons kept without a position for the fingerprints), experiment=realwalks with a map prior trained on
# simulated procedural buildings (trained once, reused), the floor classifier on the three floors in one dataset,
# then docs/results/ilc20_<floor>.md, docs/results-ilc20.md and the README table. RW_RUNS runs per walk.
# Second map prior (leave one floor out): for each floor F, a prior trained on the train walks of the other floors
# (experiment=mapprior_ilc on their realwalks train-ids, waypoints interpolated linearly at training time; trained once, reused when
# $(RW_FLOOR_PRIOR)_not_F_onnx exists), run on F's learned-map rows (experiment=mapprior_ilc_rows, model=) into
# $(RW_OUT_OTHER)/F; python -m blenav.cli.realwalks priors writes both priors' rows beside the heuristic map PF.
RW_RAW ?= ../shared/data/raw/ilc20
RW_DATA ?= data/ilc20
RW_OUT ?= data/results/realwalks
RW_RUNS ?= 1
RW_FLOORS ?= F1 F2 B1
RW_PRIOR ?= data/runs/realwalks_mapprior_onnx
RW_PRIOR_SIM = sim=procedural seed=4 duration_s=200 'sim.carriers=[pedestrian]' sim.unlabelled_every=0 sessions=16
RW_FLOOR_PRIOR ?= data/runs/realwalks_prior
RW_FLOOR_EPOCHS ?= 8
RW_OUT_OTHER ?= data/results/realwalks_other_floors
realwalks-tables: $(STAMP)
	test -e $(RW_PRIOR)/meta.json || { \
	  $(BIN)/blenav-sim $(RW_PRIOR_SIM) out=data/realwalks_prior_sim overwrite=true progress=false && \
	  $(BIN)/python train.py experiment=mapprior data=data/realwalks_prior_sim out=data/runs/realwalks_mapprior \
	      'data.val_buildings=[procedural_006,procedural_007]' trainer.max_epochs=15 && \
	  $(BIN)/python export.py ckpt=data/runs/realwalks_mapprior/last.ckpt out=$(RW_PRIOR); }
	for F in $(RW_FLOORS); do \
	  rm -rf $(RW_DATA)/imported_$$F $(RW_DATA)/mapped_$$F $(RW_DATA)/$$F && \
	  $(BIN)/blenav-import ilc20 $(RW_RAW)/site1_$$F.tar.gz $(RW_DATA)/imported_$$F && \
	  $(BIN)/blenav-map $(RW_DATA)/imported_$$F --out $(RW_DATA)/mapped_$$F --keep-unplaced \
	      --sessions $$($(BIN)/python -m blenav.cli.realwalks train-ids $(RW_DATA)/imported_$$F) && \
	  cp -r $(RW_DATA)/imported_$$F $(RW_DATA)/$$F && \
	  cp $(RW_DATA)/mapped_$$F/buildings/site1/anchors.csv $(RW_DATA)/$$F/buildings/site1/anchors.csv && \
	  $(BIN)/blenav-eval overwrite=true experiment=realwalks data=$(RW_DATA)/$$F runs=$(RW_RUNS) model_path=$(RW_PRIOR) \
	      out=$(RW_OUT)/$$F progress=false || exit 1; done
	rm -rf $(RW_DATA)/raw_site $(RW_DATA)/site1 && mkdir -p $(RW_DATA)/raw_site
	for F in $(RW_FLOORS); do tar -xzf $(RW_RAW)/site1_$$F.tar.gz -C $(RW_DATA)/raw_site || exit 1; done
	$(BIN)/blenav-import ilc20 $(RW_DATA)/raw_site/site1 $(RW_DATA)/site1
	$(BIN)/blenav-eval overwrite=true experiment=realwalks_floors data=$(RW_DATA)/site1 runs=1 out=$(RW_OUT)/floors progress=false
	$(BIN)/python -m blenav.cli.realwalks tables $(RW_OUT) docs/results-ilc20.md $(RW_OUT)/floors README.md
	for F in $(RW_FLOORS); do \
	  O=$$(echo $(RW_FLOORS) | tr ' ' '\n' | grep -vx $$F); FIRST=$$(echo $$O | cut -d' ' -f1); \
	  REST=$$(for G in $$O; do test $$G = $$FIRST || printf '%s,' $(RW_DATA)/$$G; done | sed 's/,$$//'); \
	  IDS=$$(for G in $$O; do $(BIN)/python -m blenav.cli.realwalks train-ids $(RW_DATA)/$$G; done | paste -sd,); \
	  test -e $(RW_FLOOR_PRIOR)_not_$${F}_onnx/meta.json || { \
	    $(BIN)/python train.py experiment=mapprior_ilc data=$(RW_DATA)/$$FIRST "data.extra_paths=[$$REST]" "data.sessions=[$$IDS]" \
	        trainer.max_epochs=$(RW_FLOOR_EPOCHS) out=$(RW_FLOOR_PRIOR)_not_$$F plots=false && \
	    $(BIN)/python export.py ckpt=$(RW_FLOOR_PRIOR)_not_$$F/last.ckpt out=$(RW_FLOOR_PRIOR)_not_$${F}_onnx; } && \
	  $(BIN)/blenav-eval overwrite=true experiment=mapprior_ilc_rows data=$(RW_DATA)/$$F runs=$(RW_RUNS) \
	      model_path=$(RW_FLOOR_PRIOR)_not_$${F}_onnx out=$(RW_OUT_OTHER)/$$F progress=false || exit 1; done
	$(BIN)/python -m blenav.cli.realwalks priors $(RW_OUT) $(RW_OUT_OTHER) '$(RW_FLOOR_PRIOR)_not_{floor}_onnx' \
	    docs/results-ilc20.md README.md

# Issue 31: the learned inertial odometry, leave one floor out on the ILC floors (imported by realwalks-tables, or here
# when absent): for each floor F, a model trained on the other floors' train walks plus simulated walks (IO_SIM), exported,
# and experiment=realwalks_inertial on F with io_model= into $(IO_OUT)/F; a model trained on the simulated walks only, run
# on every floor into $(IO_OUT)/sim_F; docs/results-inertial.md from those results and the runs' training.json. Trained
# once: a run folder with its export is reused (delete $(IO_RUNS)_* to retrain); IO_MODEL picks the network (its runs
# are named after it).
IO_OUT ?= data/results/inertial
IO_RUNS ?= data/runs/inertial
IO_MODEL ?= inertial_tcn
IO_SIM = sim=procedural seed=11 duration_s=120 sim.unlabelled_every=0 sessions=12
inertial-tables: $(STAMP)
	for F in $(RW_FLOORS); do test -d $(RW_DATA)/imported_$$F || \
	  $(BIN)/blenav-import ilc20 $(RW_RAW)/site1_$$F.tar.gz $(RW_DATA)/imported_$$F || exit 1; done
	test -d data/inertial_sim || $(BIN)/blenav-sim $(IO_SIM) out=data/inertial_sim progress=false
	SIMIDS=$$(ls data/inertial_sim/sessions | paste -sd,); \
	for F in $(RW_FLOORS); do \
	  O=$$(echo $(RW_FLOORS) | tr ' ' '\n' | grep -vx $$F); \
	  EXTRA=$$(for G in $$O; do printf '%s,' $(RW_DATA)/imported_$$G; done | sed 's/,$$//'); \
	  IDS=$$(for G in $$O; do $(BIN)/python -m blenav.cli.realwalks train-ids $(RW_DATA)/imported_$$G; done | paste -sd,); \
	  test -e $(IO_RUNS)_$(IO_MODEL)_not_$${F}_io/meta.json || { \
	    $(BIN)/python train.py experiment=inertial model=$(IO_MODEL) data=data/inertial_sim \
	        "data.extra_paths=[$$EXTRA]" "data.sessions=[$$IDS,$$SIMIDS]" \
	        out=$(IO_RUNS)_$(IO_MODEL)_not_$$F plots=false trainer.enable_progress_bar=false && \
	    $(BIN)/python export.py ckpt=$(IO_RUNS)_$(IO_MODEL)_not_$$F/last.ckpt out=$(IO_RUNS)_$(IO_MODEL)_not_$${F}_io; } && \
	  $(BIN)/blenav-eval overwrite=true experiment=realwalks_inertial data=$(RW_DATA)/imported_$$F runs=$(RW_RUNS) \
	      io_model=$(IO_RUNS)_$(IO_MODEL)_not_$${F}_io out=$(IO_OUT)/$$F progress=false || exit 1; done
	test -e $(IO_RUNS)_$(IO_MODEL)_sim_io/meta.json || { \
	  $(BIN)/python train.py experiment=inertial model=$(IO_MODEL) data=data/inertial_sim out=$(IO_RUNS)_$(IO_MODEL)_sim plots=false \
	      trainer.enable_progress_bar=false && \
	  $(BIN)/python export.py ckpt=$(IO_RUNS)_$(IO_MODEL)_sim/last.ckpt out=$(IO_RUNS)_$(IO_MODEL)_sim_io; }
	for F in $(RW_FLOORS); do \
	  $(BIN)/blenav-eval overwrite=true experiment=realwalks_inertial data=$(RW_DATA)/imported_$$F runs=$(RW_RUNS) \
	      io_model=$(IO_RUNS)_$(IO_MODEL)_sim_io out=$(IO_OUT)/sim_$$F progress=false || exit 1; done
	$(BIN)/python -m blenav.cli.realwalks runs-json $(IO_OUT)/runs.json $(foreach F,$(RW_FLOORS),$(IO_RUNS)_$(IO_MODEL)_not_$(F)) $(IO_RUNS)_$(IO_MODEL)_sim
	$(BIN)/python -m blenav.cli.realwalks inertial $(IO_OUT) docs/results-inertial.md

# Issue 27: twelve experiments, shrunk (5 min), rerun and compared bit for bit with the reference snapshot (exit 1 on
# a difference); what it covers and how to refresh the reference: tools/regression_snapshot.py
regression-check: $(STAMP)
	$(BIN)/python tools/regression_snapshot.py check --work data/regression --ref tests/regression/snapshot_20d9ec8.json

clean-demo:
	rm -rf $(DEMO)
