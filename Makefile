# The two commands a new user needs: `make run` and `make test`.
# Both create/refresh .venv, install slamfront (pinned by constraints.txt) and the
# system libraries it needs, then run the demo recipe or the tests (which also need
# chromium, to open report.html: installed as root, else the apt command is printed).

PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.slamfront-installed

.PHONY: run test setup sysdeps testdeps bench clean lock

run: setup
	$(BIN)/slamfront run demo

test: setup testdeps
	$(BIN)/python -m pytest

setup: $(STAMP)

$(STAMP): pyproject.toml constraints.txt examples/slamfront-example-plugin/pyproject.toml | sysdeps
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[dev]'
	$(BIN)/python -m pip install --quiet -c constraints.txt -e examples/slamfront-example-plugin
	touch $(STAMP)

# Open3D's wheel links libusb-1.0; install it when missing (as root), else say how.
sysdeps:
	@sh scripts/sysdeps.sh

# The report test opens report.html in Debian's headless chromium.
testdeps:
	@sh scripts/sysdeps.sh test

bench: setup
	for script in benchmarks/bench_*.py; do $(BIN)/python $$script || exit 1; done

# Refresh the pinned versions from the current venv (after changing pyproject.toml).
lock: setup
	$(BIN)/python -m pip freeze --exclude-editable | grep -v '^-e' > constraints.txt

clean:
	rm -rf $(VENV) build *.egg-info
