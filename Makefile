# dockbench: `make demo` (set up, render a small dataset, evaluate it, print the table)
#            `make test` (set up, run the whole test suite)
PY    ?= $(shell command -v python3.11 || command -v python3)
VENV  := .venv
BIN   := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp

.PHONY: setup chromium demo test test-slow bench clean

$(STAMP): pyproject.toml
	$(PY) -c 'import sys; assert sys.version_info[:2] == (3, 11), "dockbench needs Python 3.11 (bpy 5.0.1 wheels are cp311-only)"'
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[render,apriltag,dev]"
	touch $(STAMP)

setup: $(STAMP)

demo: setup
	$(BIN)/dockbench generate configs/quickstart.yaml -o out/demo/dataset
	$(BIN)/dockbench evaluate out/demo/dataset -l led -l qr -l aruco -o out/demo/results

# the leaderboard test opens the page in headless Chromium (Debian package)
chromium:
	@command -v chromium >/dev/null 2>&1 || { command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ] \
	  && (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
	  || echo "chromium not installed: the leaderboard browser test will be skipped"; }

test: setup chromium
	$(BIN)/python -m pytest -q

test-slow: setup
	$(BIN)/python -m pytest -q --slow

bench: setup
	$(BIN)/dockbench bench stages

clean:
	rm -rf out .pytest_cache .hypothesis
