# Two entry points on a fresh machine: `make demo` (the main job) and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test test-slow test-all lint test-vcan soak bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/edge-monitor demo

# The suite without the tests marked slow, on every core (pytest-xdist; a test module stays on one worker,
# so its module-scoped fixtures are built once). docs/BENCHMARKS.md "Test suite" has its duration.
test: $(STAMP)
	$(PY) -m pytest -q -n auto --dist loadfile -m "not slow"

# The tests marked slow: end-to-end runs with real processes, the demo, the wheel in a fresh venv.
test-slow: $(STAMP)
	$(PY) -m pytest -q -n auto --dist loadfile -m slow

test-all: test test-slow

# Static checks (configured in pyproject.toml): ruff (style, imports, bugbear) and mypy.
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy

# SocketCAN for real: sim → vcan0 → agent inside a qemu guest (docs/RELIABILITY.md); ~2 min.
# Fetches qemu/busybox (apt, as root) and a Debian kernel (cached in .cache/) when missing.
test-vcan: $(STAMP)
	VCAN_QEMU=1 $(PY) -m pytest -q tests/test_vcan_qemu.py

# Soak with chaos (docs/RELIABILITY.md): simulator, agent, Zenoh router and subscriber as processes over
# the pty link; agent kill -9, router and controller restarts, bus silence; every frame and cycle reconciled.
soak: $(STAMP)
	$(PY) tools/soak/soak.py --duration 60 --json

bench: $(STAMP)
	$(PY) -m pip install --quiet -e '.[test,bench]'
	$(PY) tools/bench/bench_all.py

clean:
	rm -rf $(VENV) build *.egg-info
