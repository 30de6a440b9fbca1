# One-command entry points. `make demo` and `make test` each build .venv from nothing.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup demo test lint bench bench-quick bench-peers clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# the CPU wheel on disk; a plain `torch` requirement would pull a multi-GB CUDA build
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/tl-gym train --env TLCarNav-v0 --task 2 --agent tlps --iterations 50 --seed 0 --out runs/demo

test: $(STAMP)
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -n 2 -q tl_gym envs agents cli tests README.md docs

lint: $(STAMP)
	$(VENV)/bin/ruff check .

# Every benchmark script in turn (hours; the learning benchmark is almost all of it); bench-quick is the CI
# smoke run. They run in this order and stop at the first that fails.
BENCH_SCRIPTS := bench_robustness bench_env bench_agents reproduce_paper

bench: $(STAMP)
	$(foreach script,$(BENCH_SCRIPTS),$(PY) -m benchmarks.$(script) &&) true

bench-quick: $(STAMP)
	$(foreach script,$(BENCH_SCRIPTS),$(PY) -m benchmarks.$(script) --quick &&) true

# The engine against rtamt, argus, STLRom, stlcg++ and stljax, in their own virtualenv
# (STLRom builds from source: apt-get install bison flex).
.venv-bench/.installed: pyproject.toml benchmarks/requirements-peers.txt
	$(PYTHON) -m venv .venv-bench
	.venv-bench/bin/python -m pip install --quiet torch==2.13.0
	.venv-bench/bin/python -m pip install --quiet -e . -r benchmarks/requirements-peers.txt
	touch .venv-bench/.installed

bench-peers: .venv-bench/.installed
	.venv-bench/bin/python -m benchmarks.bench_robustness

clean:
	rm -rf $(VENV) .venv-bench build dist *.egg-info
