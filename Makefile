# Two entry points: `make demo` and `make test` (`make test-all` adds the slow tests). Both install into .venv first; the
# install re-runs only when pyproject.toml or the install script changes.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test test-all test-fast docs install clean

install: $(STAMP)

$(STAMP): pyproject.toml tools/install_venv.sh
	PYTHON=$(PYTHON) VENV=$(VENV) bash tools/install_venv.sh
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m robomorph.demo

# The report test renders the dashboard in Debian's chromium and the sweep test runs a
# throw-away PostgreSQL server: both Debian packages are installed when missing.
# -n auto: one pytest worker per core (pytest-xdist); --dist loadfile keeps a test file on one
# worker, so the models a file's fixtures train are trained once, not once per worker.
# `make test` is the suite without the tests marked slow (every benchmark script end to end, the
# docs site's strict build and examples, the wheel, the PostgreSQL sweep, ...): about half the
# time. `make test-all` runs them too; CI (.ci/run) runs test-all.
PYTEST_WORKERS ?= auto
PYTEST := $(PY) -m pytest -q -n $(PYTEST_WORKERS) --dist loadfile
test: $(STAMP)
	bash tools/ensure_chromium.sh
	$(PYTEST) -m "not slow"

test-all: $(STAMP)
	bash tools/ensure_chromium.sh
	bash tools/ensure_postgres.sh
	$(PYTEST)

# The same as `make test` (its name before test-all existed).
test-fast: test

# The documentation site, offline, into site/ (open site/index.html); --strict turns a broken
# link, a missing page or a failed include into an error.
# NO_MKDOCS_2_WARNING: Material's end-of-life banner is advice to its maintainers, not a build warning.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict --site-dir site

clean:
	rm -rf $(VENV) data results/runs site .pytest_cache
