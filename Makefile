# holofit — developer entry points. Needs only Python 3.11 and make.
PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
DOCS_STAMP := $(VENV)/.docs-installed-stamp
# one thread per process for numbers that are comparable across machines
ONE_CORE := OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 NUMBA_NUM_THREADS=1

.PHONY: install test test-all demo bench replicate lint docs clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -e '.[test,fftw]'
	@touch $(STAMP)

install: $(STAMP)

test: install
	$(ONE_CORE) $(BIN)/python -m pytest -m "not slow" -q

test-all: install
	$(ONE_CORE) $(BIN)/python -m pytest -q

demo: install
	$(BIN)/holofit demo --out demo-out

bench: install
	$(ONE_CORE) $(BIN)/python bench/run.py --out bench/results.json

# the paper's two experiments on synthetic truth (on 2 cores: rod ~6 min, Janus ~15 min, then the Dask check)
replicate: install
	$(BIN)/python bench/replicate.py --out replicate --dask-check 200

lint: install
	$(BIN)/ruff check holofit tests bench

# the documentation site (docs/, mkdocs.yml) into site/; --strict: any warning fails the build
$(DOCS_STAMP): $(STAMP) pyproject.toml
	$(BIN)/python -m pip install --quiet -e '.[docs]'
	@touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict -d site

clean:
	rm -rf $(VENV) demo-out replicate site .pytest_cache .ruff_cache
