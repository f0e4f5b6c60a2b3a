# rigidwarp — see README.md. `make test` is the project's test command.
REBAR ?= rebar3
ESCRIPT = _build/default/bin/rigidwarp
# The VM flags the rigidwarp escript runs with (rebar.config escript_emu_args).
# A 4 GB super carrier (memory beyond it comes from outside) keeps freed
# memory mapped: the heaps that bodies, buckets and the GVT process grow and
# drop then do not fault in fresh pages and unmap them again (each unmap
# stops the other core for a TLB flush); Bouncing 500 over 2000 ms on 2
# schedulers took 2.5-2.6 s without it and 1.85-2.07 s with it.
# The benchmarks and the shell run in rebar3's VM, so they get them here.
VM_FLAGS = +sbtu +MMscs 4096 +MMsco false

.PHONY: all deps build test sanitize docs viewer-test bench accuracy run shell clean

all: build

# Debian packages the build and the tests need (no hex.pm here).
deps:
	@scripts/install-deps

build: deps
	$(REBAR) escriptize

# eunit + PropEr + common_test + xref + module graph + API docs + dialyzer, then one closing count line.
test: build
	@scripts/run-tests

# The C loops' parity properties against the library built with
# AddressSanitizer and UndefinedBehaviorSanitizer (a temporary copy: the
# build's priv/rw_native.so is left alone); fails on any report.
sanitize: deps
	@MODULES=$${MODULES:-rw_native_tests,rw_native_island_tests,rw_cells_tests} scripts/sanitize

# API docs (edoc): apps/rigidwarp/doc/index.html (rigidwarp, the shell API;
# rw_scene and rw_frames, the file formats) and apps/rw_physics/doc/.
docs: deps
	$(REBAR) edoc

# The browser viewer in headless chromium (installs chromium and npm packages).
viewer-test: build
	@scripts/viewer-test

# The paper's Figures 7-10 on this machine, then `make accuracy` (minutes; not part of make test).
# BENCH_MS: simulated ms per run (default 1000); BENCH_REPEATS (default 3).
# doc/benchmarks.md is written by scripts/bench-tables (its text in doc/benchmarks.in.md).
bench: build
	@scripts/install-deps bench
	ERL_FLAGS="$(VM_FLAGS)" BENCH_MS=$${BENCH_MS:-1000} BENCH_REPEATS=$${BENCH_REPEATS:-3} $(REBAR) ct --dir bench --suite rw_bench_SUITE
	@scripts/plot-bench
	$(ESCRIPT) bench accuracy
	scripts/bench-tables --out doc/benchmarks.md

# Speed versus accuracy (about 2 minutes): substep x stride x integrator x CCD on the
# analytic scenes against their exact solution; doc/bench/accuracy.csv and .png.
accuracy: build
	@scripts/install-deps bench
	$(ESCRIPT) bench accuracy
	scripts/bench-tables --out doc/benchmarks.md

# The first thing to try: a scene end to end with a progress line and a summary.
run: build
	$(ESCRIPT) run scenarios/bouncing_200_250.json --until 2000

# The application started and the API's help printed, then the shell and its
# first prompt (-noinput starts no shell; user_drv:start/0 starts it once the
# greeting is out, OTP 25 having no shell:start_interactive/0).
shell: build
	erl $(VM_FLAGS) -pa _build/default/lib/*/ebin -config config/sys.config -noinput \
	    -eval '{ok, _} = application:ensure_all_started(rigidwarp), rigidwarp:help(), user_drv:start()'

clean:
	$(REBAR) clean -a
	rm -rf _build/test/logs apps/*/doc
