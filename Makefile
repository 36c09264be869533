# The README's two commands. Both set everything up first (idempotent: scripts/setup.sh
# skips every step whose result is already there), then do their job.
.PHONY: setup run test test-all lint

PY := .venv/bin/python

setup:
	@bash scripts/setup.sh

# The main job: the desktop explorer on the bundled demo scene.
run: setup
	.venv/bin/avgs-viewer

# The whole test suite, headless: pytest-xvfb starts its own Xvfb for the GUI tests.
test: setup
	$(PY) -m pytest -m "not slow" -q

# Also the slow training runs.
test-all: setup
	$(PY) -m pytest -q

lint: setup
	.venv/bin/lint-imports
