# gsjax — the two commands a newcomer needs are `make demo` and `make test`; each sets itself up.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# apt-get needs root: as another user, sudo without a password prompt (or the install is skipped, said so).
SUDO   := $(shell [ "$$(id -u)" = 0 ] || echo sudo -n)
APT    := DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get -y -q

.PHONY: install chromium demo lint test test-slow bench gpu-aot clean config-reference metrics-reference docs docs-quick

install: $(STAMP)

# constraints.txt pins the exact, tested versions; pyproject.toml only declares the supported ranges. uv installs
# them (12 s where pip took 81 s on the CI machine: a third of `make demo` from a fresh clone); pip where uv cannot.
UV_PIN := $(shell sed -n 's/^uv==//p' constraints.txt)
$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q "uv==$(UV_PIN)" && $(BIN)/uv pip install -q --python $(BIN)/python -c constraints.txt \
	    -e '.[test,docs]' || { echo "uv could not install the packages: pip instead"; \
	    $(BIN)/pip install -q -c constraints.txt -e '.[test,docs]'; }
	touch $(STAMP)

# The browser tests (tests/viewer/test_ui_browser.py) drive Debian's Chromium; installed here when missing.
chromium:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || [ -n "$$GSJAX_CHROMIUM" ] \
	|| { echo "installing Debian's chromium package for the browser tests (apt-get)"; \
	     $(APT) install chromium >/dev/null 2>&1 \
	     || { $(APT) update >/dev/null 2>&1 && $(APT) install chromium >/dev/null 2>&1; } \
	     || echo "could not install chromium (apt-get install chromium, as root): the browser tests will fail saying" \
	             "so; GSJAX_SKIP_BROWSER_TESTS=1 skips them"; }

demo: install
	$(BIN)/gsjax run --dataset synthetic --out outputs/demo --overwrite

# The default suite is mostly XLA compilation of tiny programs: three pytest workers (pytest-xdist, a test file each
# at a time so its module fixtures are built once; TEST_WORKERS=0: one process). Three on two cores: the suite also
# waits on its subprocesses, the browser and compile locks (warm on 2 cores: 4:17 with 2 workers, 3:40 with 3, 3:55
# with 4). (LLVM at -O0 compiled 25 % faster but broke the bitwise CB-KNN-equals-canonical tests: not used.)
TEST_WORKERS ?= 3
test: install chromium lint docs-quick
	$(BIN)/python -m pytest -q -m "not slow" $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist loadfile) tests

# ruff and mypy (both configured in pyproject.toml; mypy on the core and the evaluation); `make test` runs them first.
lint: install
	$(BIN)/ruff check .
	$(BIN)/mypy

# The documentation site (mkdocs.yml, docs/): strict, so a broken link, a missing reference or a docstring that does
# not render fails the build; `make test` builds it. The tutorials are executed (about 6 min on 2 cores from an
# empty .cache/, where mkdocs-jupyter keeps them; 3.5 min of it the hypergradient tutorial; GSJAX_DOCS_EXECUTE=false
# skips them: about 5 s). The site goes to site/.
docs: install
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet --site-dir site

# What `make test` builds: the same strict site without running the tutorials (the suite runs them at a tiny size,
# tests/test_tutorials.py); the stamp tells the browser test not to look for their figures.
docs-quick: install
	GSJAX_DOCS_EXECUTE=false NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet --site-dir site
	touch site/.tutorials-not-run

# The config reference (every field's unit, static/traced, bounds, default per preset, meaning) is generated from the
# field declarations; tests/test_config_fields.py fails when the committed file differs.
config-reference: install
	$(BIN)/gsjax config --reference docs/reference/config.md

# The metrics.json reference (docs/reference/metrics.md) and its JSON Schema (metrics.schema.json) are generated from
# RunMetrics; tests/app/test_metrics_reference.py fails when the committed files differ.
metrics-reference: install
	$(BIN)/python -m gsjax.app.metrics_reference docs/reference

test-slow: install
	$(BIN)/python -m pytest -q -m slow tests

bench: install
	$(BIN)/python experiments/bench_raster.py

# The GPU path compiled for an H100/H200 on this machine, no GPU needed (experiments/gpu_aot_check.py): a venv of its
# own with jax's CUDA 13 plugin (XLA's GPU compiler) and ptxas, at the jax version `make install` pins; nothing of it
# reaches `make test` or CI.
AOT_VENV := .venv-gpu-aot
JAX_PIN  := $(shell sed -n 's/^jax==//p' constraints.txt)
gpu-aot:
	[ -f $(AOT_VENV)/.installed ] || { $(PYTHON) -m venv $(AOT_VENV) && $(AOT_VENV)/bin/pip install -q -c constraints.txt \
	    -e . "jax-cuda13-plugin==$(JAX_PIN)" "jax-cuda13-pjrt==$(JAX_PIN)" "nvidia-cuda-nvcc>=13.0.48,<14" \
	    && touch $(AOT_VENV)/.installed; }
	$(AOT_VENV)/bin/python experiments/gpu_aot_check.py --out outputs/gpu_aot --roofline outputs/gpu_aot/roofline.json

clean:
	rm -rf $(VENV) $(AOT_VENV) outputs .pytest_cache
