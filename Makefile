# Two commands set everything up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test lint unit integration install system-deps node-deps schema soak bench clean sparkplug-proto

# setup.py builds gateway/jobs/validation/_plain.c (validation's compiled reader) and gateway/sources/opcua/_publish.c
# (the OPC UA source's PublishResponse reader) in place; a change to either reinstalls.
$(STAMP): pyproject.toml setup.py gateway/jobs/validation/_plain.c gateway/sources/opcua/_publish.c
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP)

BENCH_STAMP := $(VENV)/.bench-installed

$(BENCH_STAMP): $(STAMP)
	$(BIN)/pip install --quiet -e '.[test,bench]'
	touch $(BENCH_STAMP)

# The peer the bench measures the gateway against (bench/README.md, scenario peer): Node-RED,
# node-red-contrib-opcua and Node.js 22 (the `node` package), pinned by bench/peer/package-lock.json and
# installed by npm into bench/peer/node_modules. Only `make bench` installs it; again only when the lock changes.
PEER       := bench/peer
PEER_STAMP := $(PEER)/node_modules/.installed

$(PEER_STAMP): $(PEER)/package.json $(PEER)/package-lock.json
	@command -v npm >/dev/null 2>&1 || { echo "make bench needs npm to install its peer, Node-RED (apt-get install npm)"; exit 1; }
	cd $(PEER) && npm ci --no-audit --no-fund --loglevel=error
	touch $(PEER_STAMP)

# node-opcua, the independent OPC UA client of the umati view's test (tests/integration/umati/test_node_opcua.py),
# pinned by tests/node/package-lock.json and installed by npm into tests/node/node_modules; again only when the
# lock changes. Without npm the test is skipped, and this says so.
NODE_TESTS := tests/node
NODE_STAMP := $(NODE_TESTS)/node_modules/.installed

$(NODE_STAMP): $(NODE_TESTS)/package.json $(NODE_TESTS)/package-lock.json
	@if command -v npm >/dev/null 2>&1; then \
		cd $(NODE_TESTS) && npm ci --no-audit --no-fund --loglevel=error && touch node_modules/.installed; \
	else \
		echo "npm is absent: the node-opcua client test (tests/integration/umati/test_node_opcua.py) will be skipped (apt-get install npm)"; \
	fi

node-deps: $(NODE_STAMP)

install: $(STAMP)

# Mosquitto is a real broker the MQTT tests start on a free loopback port; Chromium runs the web console's
# browser tests (Playwright drives Debian's package; its own browser download is not used).
system-deps:
	@bash .ci/install-system-deps

demo: $(STAMP)
	$(BIN)/cnc-gateway demo

# The checks first: a finding fails `make test` (and so CI) before any test runs.
test: $(STAMP) system-deps node-deps
	@$(MAKE) --no-print-directory lint || { echo "make test: stopped, the checks above failed (run make lint)"; exit 1; }
	$(BIN)/pytest tests

# ruff (lint and format) over the code and its tests, mypy --strict on gateway/ and simulator/, and the
# import contracts in pyproject.toml (layers, no cycles; docs/architecture.md). Each runs even if one before
# it failed, so one pass lists every finding; well under a minute.
LINT_PATHS := gateway simulator bench tests
# The example plugins (a driver, an OPC UA view) that tests/integration/test_example_*.py install from their
# folders: type-checked as a third party's package would be, against the gateway's API.
EXAMPLES := tests/example_driver:tests/example_view

lint: $(STAMP)
	@failed=""; \
	echo "== ruff check"; $(BIN)/ruff check $(LINT_PATHS) || failed="$$failed ruff-check"; \
	echo "== ruff format --check"; $(BIN)/ruff format --check $(LINT_PATHS) || failed="$$failed ruff-format"; \
	echo "== mypy --strict"; $(BIN)/mypy --strict gateway simulator || failed="$$failed mypy"; \
	MYPYPATH=$(EXAMPLES) $(BIN)/mypy --strict -p cnc_example_driver -p cnc_example_view || failed="$$failed mypy-examples"; \
	echo "== import contracts"; $(BIN)/lint-imports --no-cache --no-logo || failed="$$failed import-contracts"; \
	if [ -n "$$failed" ]; then echo "make lint: FAILED:$$failed (the findings are above)"; exit 1; fi; \
	echo "make lint: ruff, ruff format, mypy --strict and the import contracts pass"

unit: $(STAMP)
	$(BIN)/pytest tests --ignore=tests/integration

integration: $(STAMP) system-deps node-deps
	$(BIN)/pytest tests/integration

# The fault drills with their soak counts: 30 broker restarts, 30 controller restarts, 50 gateway kills,
# 150,000 changes past stalled consumers, and the bad-input corpus (README: Reliability drills). ~10 min.
soak: $(STAMP) system-deps
	CNC_DRILL_SCALE=soak $(BIN)/pytest tests/integration/drills

# Throughput, latency, start-up, memory and job delivery against the raw libraries' ceilings and against
# Node-RED, measured in the same run (bench/README.md). About an hour (the serial DNC scenario's 10 MB drip alone is about half an hour); `make bench BENCH_ARGS=--quick` takes
# about three. Prints one table; the same figures go to bench/results/latest.json.
bench: $(BENCH_STAMP) $(PEER_STAMP) system-deps
	$(BIN)/python -m bench.run $(BENCH_ARGS)

schema: $(STAMP)
	$(BIN)/cnc-gateway schema > mappings/mapping.schema.json
	$(BIN)/cnc-gateway schema --gateway > mappings/gateway.schema.json

# Regenerates gateway/codecs/sparkplug/sparkplug_b_pb2.py and .pyi from sparkplug_b.proto with protoc as
# pinned in pyproject.toml (grpcio-tools, extra `proto`); tests/unit/codecs/sparkplug/test_generated.py
# fails while the committed modules and the .proto disagree.
sparkplug-proto: $(STAMP)
	$(BIN)/python -m gateway.codecs.sparkplug.protoc

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info
