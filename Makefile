# rigidwarp — see README.md. `make test` is the project's test command.
REBAR ?= rebar3
ESCRIPT = _build/default/bin/rigidwarp

.PHONY: all deps build test viewer-test run shell clean

all: build

# Debian packages the build and the tests need (no hex.pm here).
deps:
	@scripts/install-deps

build: deps
	$(REBAR) escriptize

# eunit + PropEr + common_test + xref + dialyzer, then one closing count line.
test: build
	@scripts/run-tests

# The browser viewer in headless chromium (installs chromium and npm packages).
viewer-test: build
	@scripts/viewer-test

# The first thing to try: a scene end to end with a progress line and a summary.
run: build
	$(ESCRIPT) run scenarios/bouncing_200_250.json --until 2000

shell: build
	$(REBAR) shell

clean:
	$(REBAR) clean -a
	rm -rf _build/test/logs
