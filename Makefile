# Two entry points, both safe on a fresh clone with only python3 and make:
#   make demo   set up .venv and run the main job (the multi-process demo)
#   make test   set up .venv and run the whole test suite
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test setup clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $@

demo: setup
	$(BIN)/splitspec design examples/paper_discrete.yaml
	RERUN_ANALYTICS=0 $(BIN)/splitspec run examples/paper_discrete.yaml --out out/demo

test: setup
	RERUN_ANALYTICS=0 $(BIN)/python -m pytest

clean:
	rm -rf $(VENV) build *.egg-info
