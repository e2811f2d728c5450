# Two commands do all the set-up on a fresh machine:
#   make demo   train, render and evaluate on the built-in poster scene
#   make test   run the whole test suite
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
RUN    := outputs/poster/splatu/latest

.PHONY: install demo test clean

install: $(STAMP)

# torch==2.13.0 first: on this project's machines pip finds its CPU wheel on disk, and a bare `torch` would pull a
# CUDA build. Elsewhere, install the CPU wheel into .venv first (README, Quickstart).
$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/splatu train --data poster
	$(BIN)/splatu render-uncertainty --load $(RUN)
	$(BIN)/splatu eval-ause --load $(RUN)

test: $(STAMP)
	$(BIN)/ruff check splatu tests benchmarks
	$(BIN)/python -m pytest

clean:
	rm -rf $(VENV) outputs .cache
