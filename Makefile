# Two commands on a fresh machine; each sets up whatever it needs first:
#   make demo   the main job: a local session on the embedded default (no docker, no router)
#   make test   the whole test suite (and `ruff check`)
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# the suite's parallel workers: its tests mostly wait on real time (routers, child processes,
# timeouts), so more workers than the 2 cores; each takes its own ports (tests/conftest.py)
TEST_WORKERS ?= 4
APT_PACKAGES := $(shell grep -v '^\s*\#' deploy/apt-packages.txt)

.PHONY: demo test lint setup system-packages clean

demo: setup system-packages
	$(BIN)/voxshape demo

test: setup system-packages
	$(BIN)/ruff check .
	$(BIN)/pytest -n $(TEST_WORKERS) --dist loadgroup

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

setup: $(STAMP)

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; v = sys.version_info[:2]; sys.exit(0 if v == (3, 11) else \
	  f"voxshape needs Python 3.11 (pybullet has no wheels above it), found {sys.version.split()[0]}: \
	  install python3.11 or run make PYTHON=/path/to/python3.11")'
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,cluster,whisper]'
	touch $@

system-packages:
	@missing=$$(for p in $(APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  sudo=$$([ "$$(id -u)" = 0 ] || echo sudo); \
	  echo "installing Debian packages: $$missing"; \
	  $$sudo apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $$sudo apt-get install -y -qq --no-install-recommends $$missing; \
	fi

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache .hypothesis
