# Two commands do everything: `make demo` and `make test`. Each sets the project up first
# (Debian packages, virtual environment, Python packages) and is quick the second time.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.setup-stamp
OUT    ?= out

.PHONY: setup demo test bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml scripts/setup.sh
	@bash scripts/setup.sh "$(PYTHON)" "$(VENV)"
	@touch $(STAMP)

demo: setup
	$(VENV)/bin/kitchenbot demo --out $(OUT)/demo

test: setup
	$(PY) -m pytest -q -n 2 --timeout 600

bench: setup
	$(VENV)/bin/kitchenbot bench render
	$(VENV)/bin/kitchenbot bench scenes

clean:
	rm -rf $(VENV) $(OUT)
