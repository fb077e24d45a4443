# Two commands do all set-up on a fresh machine: `make demo` and `make test`.
# Each creates .venv when missing and installs what it needs.

VENV   ?= .venv
PY     := $(VENV)/bin/python
PYTHON ?= python3
STAMP  := $(VENV)/.installed-core
# A CPU build of torch is installed before stable-baselines3 so that the `rl`
# extra never pulls a multi-gigabyte CUDA build.
TORCH_PIN := torch==2.13.0
RL_STAMP  := $(VENV)/.installed-rl
# Every integration extra, so that its tests run in CI (MetaDrive has its own venv).
EXTRAS    := sumo,highway,carla,mqtt,csi,ros2,web,v2x,ncap,city
INT_STAMP := $(VENV)/.installed-integrations

.PHONY: demo calibration-demo test lint pytest pytest-nodispatch ctest bench fuzz clean venv rl integrations metadrive metadrive-ci

venv: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev,plot,sim]'
	touch $@

$(RL_STAMP): $(STAMP)
	$(PY) -m pip install --quiet $(TORCH_PIN)
	$(PY) -m pip install --quiet -e '.[rl]'
	touch $@

rl: $(RL_STAMP)

$(INT_STAMP): $(RL_STAMP)
	$(PY) -m pip install --quiet -e '.[$(EXTRAS)]'
	touch $@

integrations: $(INT_STAMP)

# MetaDrive pulls `pygame`, which clashes with highway-env's pygame-ce: it gets a venv of
# its own. It cannot download its assets here, so a physics-only stub is written.
MD_VENV  := .venv-metadrive
MD_PY    := $(MD_VENV)/bin/python
MD_STAMP := $(MD_VENV)/.installed

$(MD_STAMP): pyproject.toml
	test -x $(MD_PY) || $(PYTHON) -m venv $(MD_VENV)
	$(MD_PY) -m pip install --quiet --upgrade pip
	$(MD_PY) -m pip install --quiet $(TORCH_PIN)
	$(MD_PY) -m pip install --quiet -e '.[metadrive]' pytest pytest-timeout stable-baselines3
	$(MD_PY) -c 'from rfsas_hw.bridges.metadrive import write_stub_assets; write_stub_assets()'
	touch $@

metadrive: $(MD_STAMP)
	$(MD_PY) -m pytest -q -ra -p no:cacheprovider tests/metadrive_sim

# In `make test`: a MetaDrive venv that cannot be built skips its tests, saying why.
metadrive-ci:
	@$(MAKE) --no-print-directory $(MD_STAMP) || echo "SKIPPED tests/metadrive_sim: could not build $(MD_VENV) (pip output above)"
	@if [ -f $(MD_STAMP) ]; then $(MD_PY) -m pytest -q -ra -p no:cacheprovider tests/metadrive_sim; fi

# `make demo DEMO_ARGS="--cpm udp://127.0.0.1:2009?btp=1"` also sends the tracks as CPMs
# (needs the v2x extra: .venv/bin/pip install -e '.[v2x]').
DEMO_ARGS ?=

demo: $(STAMP)
	$(VENV)/bin/rfsas demo $(DEMO_ARGS)

calibration-demo: $(STAMP)
	mkdir -p out
	$(VENV)/bin/rfsas calibrate calibration/example_turntable.csv -o out/example_cal.yaml --plot out/example_cal.png
	$(VENV)/bin/rfsas calibrate --check out/example_cal.yaml calibration/example_turntable_check.csv

lint: $(INT_STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy rfsas_hw

ctest:
	$(MAKE) -C firmware_protocol/c test

# Two workers: many tests wait on sockets, subprocesses and brokers, so the
# suite takes about half the wall time on a 2-core machine.
pytest: $(INT_STAMP)
	$(PY) -m pytest -q -n 2

# The numeric tests once more with numpy's run-time SIMD dispatch switched off (every
# target above the build's baseline: on x86-64 AVX2 and AVX-512; numpy names them
# itself, so this holds on any CPU), so that what they assert holds on whichever path
# a machine takes: implementations are compared within tolerances, never bit for bit.
NUMERIC_TESTS := tests/backend tests/df tests/core tests/twin
NPY_DISPATCH   = $(shell $(PY) -c "import numpy as np; s = np.show_config(mode='dicts')['SIMD Extensions']; print(' '.join(s['found'] + s['not found']))")

pytest-nodispatch: $(INT_STAMP)
	NPY_DISABLE_CPU_FEATURES="$(NPY_DISPATCH)" $(PY) -m pytest -q -n 2 $(NUMERIC_TESTS)

test: lint ctest pytest pytest-nodispatch metadrive-ci

bench: $(INT_STAMP)
	@for f in bench/bench_*.py; do echo "== $$f"; $(PY) $$f || exit 1; done

fuzz: $(STAMP)
	RFSAS_FUZZ_CASES=1000000 $(PY) -m pytest -q -m fuzz tests

clean:
	rm -rf $(VENV) $(MD_VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
