# One-command entry points. `make demo` and `make test` each build .venv from nothing.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# where pip gets torch: its own configuration by default (here: the CPU wheel on disk); elsewhere, for the CPU build,
# `make test TORCH_INDEX=https://download.pytorch.org/whl/cpu`
TORCH_INDEX ?=
TORCH := torch==2.13.0 $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX))

.PHONY: setup demo test lint bench bench-quick bench-peers clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# torch first: a plain `torch` requirement of the project could pull another (multi-GB CUDA) build
	$(PY) -m pip install --quiet $(TORCH)
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
BENCH_SCRIPTS := bench_robustness bench_gradient bench_env bench_agents reproduce_paper

bench: $(STAMP)
	$(foreach script,$(BENCH_SCRIPTS),$(PY) -m benchmarks.$(script) &&) true

bench-quick: $(STAMP)
	$(foreach script,$(BENCH_SCRIPTS),$(PY) -m benchmarks.$(script) --quick &&) true

# The engine against rtamt, argus, STLRom, stlcg++ and stljax, in their own virtualenv
# (STLRom builds from source: apt-get install bison flex).
.venv-bench/.installed: pyproject.toml benchmarks/requirements-peers.txt
	$(PYTHON) -m venv .venv-bench
	.venv-bench/bin/python -m pip install --quiet $(TORCH)
	.venv-bench/bin/python -m pip install --quiet -e . -r benchmarks/requirements-peers.txt
	touch .venv-bench/.installed

bench-peers: .venv-bench/.installed
	.venv-bench/bin/python -m benchmarks.bench_robustness

clean:
	rm -rf $(VENV) .venv-bench build dist *.egg-info
