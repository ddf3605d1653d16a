# evtools: `make demo` and `make test` do all the set-up on a fresh machine (Python >= 3.10, 3.11 preferred).
PYTHON ?= $(shell command -v python3.11 || command -v python3)
# a pipeline fails when any of its stages fails, not only the last (a cut upstream is an error downstream too)
SHELL := /bin/bash
.SHELLFLAGS := -o pipefail -c
VENV := .venv
BIN := $(VENV)/bin
OUT := samples/out

.PHONY: demo test test-numba bench fuzz docs figures clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(VENV)/.installed-test: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@ $(VENV)/.installed

# The report's scheme on one simulated camera (the same --seed draws the same threshold map in every scene):
# calibrate offline once (flicker -> bafilter -> estimate), then filter and correct a step scene online.
CAMERA := --size 64x48 --sigma-thres 0.03 --seed 7
NOISE := --leak-rate-hz 0.1 --shot-noise-rate-hz 1
STEP := scene:step $(CAMERA) --duration 3s --cutoff-hz 8 --fixed-cutoff --min-level 40 --max-level 179.25

demo: $(VENV)/.installed
	@mkdir -p $(OUT)
	$(BIN)/evtools simulate scene:flicker $(CAMERA) $(NOISE) --duration 2s --truth $(OUT)/flicker.truth.h5 \
	  -o $(OUT)/flicker.aedat4
	$(BIN)/evtools render $(OUT)/flicker.aedat4 -o $(OUT)/flicker.png --window-us 20000
	$(BIN)/evtools bafilter $(OUT)/flicker.aedat4 --method stcf --k 1 --dt-us 100000 \
	  | $(BIN)/evtools estimate - --method stimulus --stimulus-levels 50,200 --stimulus-period 500ms \
	  -o $(OUT)/thresholds.h5
	$(BIN)/evtools metrics thresholds $(OUT)/thresholds.h5 --truth $(OUT)/flicker.truth.h5 \
	  --plot $(OUT)/thresholds.png --json > $(OUT)/thresholds.json
	$(BIN)/evtools simulate $(STEP) $(NOISE) -o $(OUT)/step.aedat4
	$(BIN)/evtools simulate $(STEP) --sigma-thres 0 --leak-rate-hz 0 -o $(OUT)/step.ideal.aedat4
	$(BIN)/evtools bafilter $(OUT)/step.aedat4 --method baf --dt-us 50000 -o $(OUT)/step.filtered.aedat4
	$(BIN)/evtools correct $(OUT)/step.filtered.aedat4 --thresholds $(OUT)/thresholds.h5 -o $(OUT)/step.corrected.aedat4
	$(BIN)/evtools metrics uniformity $(OUT)/step.filtered.aedat4 --reference $(OUT)/step.ideal.aedat4 \
	  --json > $(OUT)/before.json
	$(BIN)/evtools metrics uniformity $(OUT)/step.corrected.aedat4 --reference $(OUT)/step.ideal.aedat4 \
	  --before $(OUT)/step.filtered.aedat4 --plot $(OUT)/edges.png --json > $(OUT)/after.json
	$(BIN)/evtools info $(OUT)/flicker.aedat4 $(OUT)/step.aedat4 $(OUT)/step.corrected.aedat4 --json \
	  | $(BIN)/python samples/summarize_info.py
	@$(BIN)/python samples/summarize_demo.py $(OUT)/thresholds.json $(OUT)/before.json $(OUT)/after.json
	@echo "pictures: $(OUT)/flicker.png (events), $(OUT)/thresholds.png (estimated, true, error maps)," \
	  "$(OUT)/edges.png (per-pixel reconstructions of an edge, before and after)"

# the slowest tests are listed at the end: the whole run is to stay under 10 minutes on 2 cores
test: $(VENV)/.installed-test
	$(BIN)/python -m pytest -q -n 2 --durations=15

# the tests of every module with kernels, run on numba's own dispatchers instead of the stored machine code
# (EVTOOLS_KERNELS=numba: the fence around evtools/_kernels/jit.py; .ci/run runs it after `make test`); the store's
# own tests (tests/test_jit.py) are not among them: that mode turns the store off (one of them runs both modes)
KERNEL_TESTS := tests/test_bafilter.py tests/test_correct.py tests/test_correct_exact.py tests/test_estimate.py \
  tests/test_estimate_frames.py tests/test_noise.py tests/test_simulate.py tests/test_mlpf.py \
  tests/test_metrics_reconstruction.py tests/test_hdf5.py tests/test_prophesee.py tests/test_text.py tests/test_ecf.py \
  tests/test_events.py tests/test_aedat4.py
test-numba: $(VENV)/.installed-test
	EVTOOLS_KERNELS=numba $(BIN)/python -m pytest -q -n 2 $(KERNEL_TESTS)

# the readers against 2,000 mutants of every format, each format in a child under a memory and time limit
fuzz: $(VENV)/.installed-test
	$(BIN)/python -m tests.fuzz all 2000

bench: $(VENV)/.installed-test
	$(BIN)/python -m tests.bench.bench_formats
	$(BIN)/python -m tests.bench.bench_simulate
	$(BIN)/python -m tests.bench.bench_bafilter
	$(BIN)/python -m tests.bench.bench_estimate
	$(BIN)/python -m tests.bench.bench_correct
	$(BIN)/python -m tests.bench.bench_batch
	$(BIN)/python -m tests.bench.bench_peers
	$(BIN)/python -m tests.bench.bench_latency
	$(BIN)/python -m tests.bench.bench_frames
	$(BIN)/python -m tests.bench.bench_render

# the README's figures (docs/figures/*.png), made from built-in scenes by the commands the README shows
FIGURES := docs/figures
FIG_TMP := $(OUT)/figures
figures: $(VENV)/.installed
	@mkdir -p $(FIGURES) $(FIG_TMP)
	$(BIN)/evtools simulate scene:texture --size 64x48 --seed 7 --duration 2s --speed 200 -o $(FIG_TMP)/texture.aedat4
	$(BIN)/evtools render $(FIG_TMP)/texture.aedat4 -o $(FIGURES)/events.png --start 1s --window-us 20000 --scale 6
	$(BIN)/evtools simulate scene:flicker $(CAMERA) $(NOISE) --duration 2s --truth $(FIG_TMP)/flicker.truth.h5 \
	  -o $(FIG_TMP)/flicker.aedat4
	$(BIN)/evtools bafilter $(FIG_TMP)/flicker.aedat4 --method stcf --k 1 --dt-us 100000 \
	  | $(BIN)/evtools estimate - --method stimulus --stimulus-levels 50,200 --stimulus-period 500ms \
	  -o $(FIG_TMP)/thresholds.h5
	$(BIN)/evtools render --map $(FIG_TMP)/thresholds.h5 -o $(FIGURES)/map.png
	$(BIN)/evtools metrics thresholds $(FIG_TMP)/thresholds.h5 --truth $(FIG_TMP)/flicker.truth.h5 \
	  --plot $(FIGURES)/thresholds.png > /dev/null
	$(BIN)/evtools simulate scene:bars --size 128x96 --seed 1 --duration 2s --shot-noise-rate-hz 5 \
	  --hot-pixel-fraction 0.001 --hot-pixel-rate-hz 1000 -o $(FIG_TMP)/noisy.aedat4
	$(BIN)/evtools render $(FIG_TMP)/noisy.aedat4 --rate -o $(FIGURES)/rate.png
	$(BIN)/evtools bafilter $(FIG_TMP)/noisy.aedat4 --method hotpixel --save-hot-pixels $(FIGURES)/hot.png \
	  -o $(FIG_TMP)/cool.aedat4
	$(BIN)/evtools simulate $(STEP) $(NOISE) -o $(FIG_TMP)/step.aedat4
	$(BIN)/evtools correct $(FIG_TMP)/step.aedat4 --thresholds $(FIG_TMP)/flicker.truth.h5 -o $(FIG_TMP)/corrected.aedat4
	$(BIN)/evtools metrics uniformity $(FIG_TMP)/corrected.aedat4 --before $(FIG_TMP)/step.aedat4 \
	  --plot $(FIGURES)/edge.png > /dev/null
	$(BIN)/evtools simulate scene:step --size 20x20 --duration 2s --cutoff-hz 8 --fixed-cutoff \
	  --truth $(FIG_TMP)/step20.truth.h5 -o $(FIG_TMP)/step20.aedat4
	$(BIN)/evtools correct $(FIG_TMP)/step20.aedat4 --thresholds $(FIG_TMP)/step20.truth.h5 \
	  -o $(FIG_TMP)/step20.corrected.aedat4
	$(BIN)/evtools metrics reconstruction $(FIG_TMP)/step20.corrected.aedat4 --truth $(FIG_TMP)/step20.truth.h5 \
	  --contrast 0.2 --plot $(FIGURES)/reconstruction.png > /dev/null
	@echo "figures: $(FIGURES)/*.png"

# the API reference from the docstrings (pdoc, an optional extra) into docs/api/
docs: $(VENV)/.installed
	$(BIN)/python -m pip install --quiet -e '.[docs]'
	$(BIN)/python -m pdoc evtools evtools.api evtools.events evtools.filters evtools.estimation evtools.correction \
	  evtools.simulation evtools.noise evtools.metrics evtools.formats -o docs/api --docformat numpy
	@echo "API reference: docs/api/index.html"

clean:
	rm -rf $(OUT) .pytest_cache .hypothesis
