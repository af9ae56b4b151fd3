# Glint: `make serve` and `make test` do all set-up on a fresh machine.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: install build serve test bench clean

$(STAMP): pyproject.toml setup.py worker/native/src/glintk.c
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip setuptools wheel
	$(PY) -m pip install -q -e '.[test]'
	$(PY) setup.py -q build_ext --inplace
	touch $(STAMP)

install: $(STAMP)

build: install
	$(PY) setup.py -q build_ext --inplace

# Until the service exists (issue 4), serving renders the demo scene and says where it is.
serve: install
	$(VENV)/bin/glint demo --out out/demo.png

test: install
	OPENBLAS_NUM_THREADS=1 $(PY) -m pytest -q -ra

bench: install
	$(VENV)/bin/glint bench render tests/scenes/bunny.json --frames 60 --json

clean:
	rm -rf build $(VENV) worker/native/*.so .pytest_cache tests/.cache
