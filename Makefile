# photonmap — set-up, demo, tests and benchmarks. Everything installs into .venv from scratch.
# The demo needs libLLVM and the package; the tests add their tools, Ray and Chromium (for the
# viewer's browser tests).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
BASE   := $(VENV)/.installed
DEV    := $(VENV)/.installed-dev

.PHONY: demo test bench lint clean

$(BASE): pyproject.toml scripts/ensure-llvm.sh
	bash scripts/ensure-llvm.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e .
	touch $(BASE)

$(DEV): $(BASE) scripts/ensure-chromium.sh
	bash scripts/ensure-chromium.sh
	$(PY) -m pip install -q -e ".[dev,cluster]"
	touch $(DEV)

demo: $(BASE)
	mkdir -p out
	$(VENV)/bin/photonmap render glass_sphere_fog -o out/demo.png -o out/demo.exr --timings

test: $(DEV)
	$(PY) scripts/test_suite.py

bench: $(DEV)
	$(PY) benchmarks/volume_table1.py
	$(PY) benchmarks/adaptive_vs_reference.py
	$(PY) benchmarks/surface_vs_path.py
	$(PY) benchmarks/knn_throughput.py
	$(PY) benchmarks/screen_table1.py
	$(PY) benchmarks/volume_vs_volpath.py
	$(PY) benchmarks/viewer_latency.py
	$(PY) benchmarks/caustics_vs_path.py
	$(PY) benchmarks/scale_out.py
	$(PY) benchmarks/steinhurst_tables.py
	$(PY) benchmarks/steinhurst_ic_cis.py
	$(PY) benchmarks/steinhurst_table_5_1.py
	$(PY) benchmarks/steinhurst_o17_study.py
	$(PY) benchmarks/volume_box_grid.py
	$(PY) benchmarks/user_scenes.py
	$(PY) benchmarks/first_render.py

lint: $(DEV)
	$(VENV)/bin/ruff check src tests benchmarks examples

clean:
	rm -rf $(VENV) out
