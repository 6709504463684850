# dockbench: `make demo` (set up, render a small dataset, evaluate it, print the table)
#            `make test` (set up, run the whole test suite)
# Development: `make test-fast` (unit tests: no Blender render, install or Ray; ~100 CPU s),
#              `make lint` (ruff lint + format check, mypy on datasets_spec and evalkit).
# The render stack is Python 3.13 + bpy 5.2 LTS (bpy >= 5.1 ships for 3.13 only). The exact tested
# set is constraints/py313.txt; pyproject.toml keeps ranges so the evaluator installs anywhere.
# The first python3.13 that really runs (a pyenv shim on the PATH may not, where 3.13 is not `pyenv global`).
PY    ?= $(shell for p in python3.13 $(HOME)/.pyenv/versions/3.13*/bin/python3.13 /usr/local/bin/python3.13 /usr/bin/python3.13; do \
           "$$p" -c 'import sys; assert sys.version_info[:2] == (3, 13)' >/dev/null 2>&1 && { command -v "$$p"; break; }; done)
VENV  := .venv
BIN   := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
CONSTRAINTS := constraints/py313.txt

.PHONY: setup chromium sandbox demo test test-fast test-slow lint bench clean

$(STAMP): pyproject.toml $(CONSTRAINTS)
	@[ -n "$(PY)" ] && "$(PY)" -c 'import sys; assert sys.version_info[:2] == (3, 13)' 2>/dev/null || { \
	  echo "dockbench's render stack needs Python 3.13 (bpy 5.2 wheels are cp313-only)." >&2; \
	  echo "Install it (e.g. 'pyenv install 3.13' or your distribution's python3.13) or run 'make PY=/path/to/python3.13'." >&2; \
	  echo "Evaluation alone installs on Python 3.11-3.13: pip install dockbench (no render extra)." >&2; exit 2; }
	"$(PY)" -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	@# setuptools' notice about editable installs is advice, not a problem: keep the set-up quiet
	PYTHONWARNINGS="ignore:Editable installation" \
	  $(BIN)/python -m pip install --quiet -c $(CONSTRAINTS) -e ".[render,apriltag,ray,dev]"
	touch $(STAMP)

setup: $(STAMP) sandbox

demo: setup
	$(BIN)/dockbench generate configs/quickstart.yaml -o out/demo/dataset
	$(BIN)/dockbench evaluate out/demo/dataset -l led -l qr -l aruco -l hybrid -o out/demo/results --overwrite

# the leaderboard test opens the page in headless Chromium (Debian package)
chromium:
	@command -v chromium >/dev/null 2>&1 || { command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ] \
	  && (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
	  || echo "chromium not installed: the leaderboard browser test will be skipped"; }

# isolated localizers run inside bubblewrap (Debian package; datasets_spec/LOCALIZER_PROTOCOL.md, Sandbox)
sandbox:
	@command -v bwrap >/dev/null 2>&1 || { command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ] \
	  && (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq bubblewrap >/dev/null) \
	  || echo "bubblewrap not installed: isolated localizers run unsandboxed and the sandbox tests are skipped"; }

test: setup chromium
	$(BIN)/python -m pytest -q

# unit tests only: pure numpy/OpenCV, no Blender render, no wheel install, no Ray runtime
test-fast: setup
	$(BIN)/python -m pytest -q -m "not blender and not install and not ray and not integration and not heavy"

# the code style the project holds (pyproject.toml [tool.ruff], [tool.mypy]); CI runs it (.ci/run)
lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

test-slow: setup
	$(BIN)/python -m pytest -q --slow

bench: setup
	$(BIN)/dockbench bench stages -o out/bench

clean:
	rm -rf out .pytest_cache .hypothesis
