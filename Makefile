# Shortcuts for the README's two commands (scripts/run.sh, scripts/test.sh), which need
# nothing but bash on a fresh Debian machine.
.PHONY: setup run test test-all lint

setup:
	@bash scripts/setup.sh

run:
	@bash scripts/run.sh

test:
	@bash scripts/test.sh

# Also the slow training runs.
test-all:
	@bash scripts/test.sh -m ""

lint: setup
	.venv/bin/lint-imports
