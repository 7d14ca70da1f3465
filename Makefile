# The two commands a new user needs: `make run` and `make test` (Python 3.11+).
# Both create/refresh .venv, install slamfront (pinned by constraints.txt) and the
# system libraries it needs, then run the demo recipe or the tests. `make test` first
# checks the real test data in the data root (docs/data.md) and fetches what is missing:
# nothing when it is all there, one line per missing dataset when offline. The tests also
# need chromium, to open report.html (installed as root, else the apt command is printed).

PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.slamfront-installed

.PHONY: run test setup sysdeps testdeps bench clean lock

run: setup
	$(BIN)/slamfront run demo

test: setup testdeps
	$(BIN)/slamfront datasets fetch --for-tests
	$(BIN)/python -m pytest

setup: $(STAMP)

# setuptools says "Editable installation ... be careful with folders named like the
# package" on every editable install; the layout here is deliberate, so it is noise.
QUIET_EDITABLE := PYTHONWARNINGS="ignore:Editable installation"

$(STAMP): pyproject.toml setup.py constraints.txt examples/slamfront-example-plugin/pyproject.toml | sysdeps
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || { echo 'slamfront needs Python 3.11 or newer (make PYTHON=python3.11 ...)' >&2; exit 1; }
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(QUIET_EDITABLE) $(BIN)/python -m pip install --quiet -c constraints.txt -e '.[dev]'
	$(QUIET_EDITABLE) $(BIN)/python -m pip install --quiet -c constraints.txt -e examples/slamfront-example-plugin
	touch $(STAMP)

# Open3D's wheel links libusb-1.0; install it when missing (as root), else say how.
sysdeps:
	@sh scripts/sysdeps.sh

# The report test opens report.html in Debian's headless chromium.
testdeps:
	@sh scripts/sysdeps.sh test

bench: setup
	@sh scripts/sysdeps.sh bench
	for script in benchmarks/bench_*.py; do $(BIN)/python $$script || exit 1; done

# Refresh the pinned versions from the current venv (after changing pyproject.toml).
lock: setup
	$(BIN)/python -m pip freeze --all --exclude-editable | grep -v -e '^-e' -e '^pip==' > constraints.txt

clean:
	rm -rf $(VENV) build dist *.egg-info
