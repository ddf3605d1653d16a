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
	$(BIN)/python samples/make_sample.py -o $(OUT)/sample.aedat4
	@for f in $(FORMATS); do echo "+ evtools convert $(OUT)/sample.aedat4 -o $(OUT)/sample.$$f"; \
	  $(BIN)/evtools convert $(OUT)/sample.aedat4 -o $(OUT)/sample.$$f || exit 1; done
	$(BIN)/evtools convert $(OUT)/sample.aedat4 - | $(BIN)/evtools convert - -o $(OUT)/sample.piped.h5
	$(BIN)/evtools info $(OUT)/sample.aedat4 $(foreach f,$(FORMATS),$(OUT)/sample.$(f)) $(OUT)/sample.piped.h5 --json \
	  | $(BIN)/python samples/summarize_info.py

test: $(VENV)/.installed-test
	$(BIN)/python -m pytest -q

bench: $(VENV)/.installed-test
	$(BIN)/python -m tests.bench.bench_formats

clean:
	rm -rf $(OUT) .pytest_cache .hypothesis
