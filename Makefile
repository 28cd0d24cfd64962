# Two commands set everything up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test unit integration install system-deps schema clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

# Mosquitto is a real broker the MQTT tests start on a free loopback port.
system-deps:
	@bash .ci/install-system-deps

demo: $(STAMP)
	$(BIN)/cnc-gateway demo

test: $(STAMP) system-deps
	$(BIN)/pytest tests

unit: $(STAMP)
	$(BIN)/pytest tests --ignore=tests/integration

integration: $(STAMP) system-deps
	$(BIN)/pytest tests/integration

schema: $(STAMP)
	$(BIN)/cnc-gateway schema > mappings/mapping.schema.json

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info
