# evtools: `make demo` and `make test` do all the set-up on a fresh machine (Python >= 3.10, 3.11 preferred).
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
OUT := samples/out
FORMATS := aedat4 aedat h5 csv txt

.PHONY: demo test bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(VENV)/.installed-test: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@ $(VENV)/.installed

demo: $(VENV)/.installed
	@mkdir -p $(OUT)
	$(BIN)/evtools simulate scene:bars --size 128x96 --duration 1s --preset noisy --seed 1 \
	  --truth $(OUT)/bars.truth.h5 -o $(OUT)/bars.aedat4
	$(BIN)/evtools render $(OUT)/bars.aedat4 -o $(OUT)/bars.png --window-us 20000
	$(BIN)/evtools render $(OUT)/bars.aedat4 -o $(OUT)/bars.mp4 --window-us 20000
	$(BIN)/evtools render --map $(OUT)/bars.truth.h5 -o $(OUT)/bars.thresholds.png
	@for f in $(FORMATS); do echo "+ evtools convert $(OUT)/bars.aedat4 -o $(OUT)/bars.converted.$$f"; \
	  $(BIN)/evtools convert $(OUT)/bars.aedat4 -o $(OUT)/bars.converted.$$f || exit 1; done
	$(BIN)/evtools convert $(OUT)/bars.aedat4 - | $(BIN)/evtools convert - -o $(OUT)/bars.piped.h5
	$(BIN)/evtools info $(OUT)/bars.aedat4 $(foreach f,$(FORMATS),$(OUT)/bars.converted.$(f)) $(OUT)/bars.piped.h5 \
	  --json | $(BIN)/python samples/summarize_info.py
	@echo "pictures: $(OUT)/bars.png (events), $(OUT)/bars.mp4 (video), $(OUT)/bars.thresholds.png (threshold maps)"

test: $(VENV)/.installed-test
	$(BIN)/python -m pytest -q

bench: $(VENV)/.installed-test
	$(BIN)/python -m tests.bench.bench_formats
	$(BIN)/python -m tests.bench.bench_simulate
	$(BIN)/python -m tests.bench.bench_bafilter
	$(BIN)/python -m tests.bench.bench_estimate
	$(BIN)/python -m tests.bench.bench_correct

clean:
	rm -rf $(OUT) .pytest_cache .hypothesis
