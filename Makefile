# vbrender - plain Makefile. Out-of-tree objects with dependency files.
#
#   make deps    install the Debian packages the project needs (idempotent)
#   make all     bin/vbrender, bin/vbrender-master, bin/vbrender-worker and
#                the libraries: build/libvbcore.a (renderer core, no
#                networking) and build/libvbnet.a (protocol, master, worker)
#   make check   deps, build, all tests, the dashboard in headless Chromium
#                (test-browser), then the same tests under ASan+UBSan,
#                then the multi-threaded ones under ThreadSanitizer (test-tsan)
#                then a short libFuzzer pass of every fuzz target (fuzz-short)
#   make fuzz    every fuzz target under libFuzzer (clang, ASan+UBSan, in
#                build-fuzz/), 1,000,000 runs each on a copy of its corpus
#   make fuzz-seeds   rewrite the seed corpora made by the project's writers
#   make demo    deps, build, render scenes/cornell-box.json to out/
#   make bench   deps, build, core, distributed, durable, verification,
#                CURVE and preview benchmarks (bench/results/)
#   make bench-error   the error study: the samplers (run-sampler.sh), adaptive modes
#                      against uniform and Mitsuba 3, and Mitsuba's own scene files
#                      (bench/mitsuba-scenes/run.sh, with MITSUBA_DATA)
#   make format        clang-format every tracked C file in place
#   make format-check  fail if any tracked C file differs from clang-format's output

BUILD    ?= build
SAN      ?= 0
CC       ?= cc
BIN       = bin

DEB_PACKAGES = build-essential pkg-config libembree-dev libzmq3-dev \
               libopenexr-dev libcjson-dev libexpat1-dev zlib1g-dev libjpeg-dev libstb-dev check libsubunit-dev libpng-dev \
               libsodium-dev nftables clang libclang-rt-14-dev clang-format \
               libmicrohttpd-dev chromium fonts-liberation
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

# Determinism: no -ffast-math, no FMA contraction, no -march=native (the same
# binary must give the same bits on every host it runs on).
# Our folders are -iquote, not -I: with -Imaster, the C library's
# #include <sched.h> (from pthread.h) found master/sched.h, and every
# header it pulls in counted as a system header, left out of the -MMD
# dependency files (an edit to scene.h did not rebuild client/vbrender.o).
CFLAGS_COMMON = -std=c11 -Wall -Wextra -Werror -pthread -ffp-contract=off \
                -fno-math-errno -D_DEFAULT_SOURCE -MMD -MP -g \
                -iquote common -iquote proto -iquote master -iquote worker \
                -I/usr/include/OpenEXR -I/usr/include/cjson
ifeq ($(SAN),1)
  OPT      = -O1 -fsanitize=address,undefined -fno-sanitize-recover=undefined \
             -fno-omit-frame-pointer
  LDSAN    = -fsanitize=address,undefined
  BUILD    = build-asan
  BIN      = build-asan/bin
else
  OPT      = -O2
  LDSAN    =
endif
# ThreadSanitizer (SAN=thread, make test-tsan): its own tree, as ASan's.
# -O1 keeps the slowdown tolerable and the stacks readable. gcc 12's
# -Wformat-truncation loses the bounds of an indexed array under
# -fsanitize=thread and flags snprintf of a PATHLEN string into PATHLEN + 16
# bytes in test_cluster.c as "up to 65535": off here only; the plain and
# ASan builds keep it.
ifeq ($(SAN),thread)
  OPT      = -O1 -fsanitize=thread -fno-omit-frame-pointer -Wno-format-truncation
  LDSAN    = -fsanitize=thread
  BUILD    = build-tsan
  BIN      = build-tsan/bin
endif
# FUZZ=1: the libFuzzer build (make fuzz, fuzz-short): clang, every source
# instrumented for libFuzzer's coverage under ASan+UBSan, and the fuzz
# targets linked with libFuzzer's main instead of tests/fuzzdriver.c.
# (libclang-rt-14-dev holds libFuzzer; clang only recommends it.)
FUZZ     ?= 0
ifeq ($(FUZZ),1)
  CC       = clang
  # (-Wno-unknown-warning-option: scene.c silences a GCC-only warning)
  OPT      = -O1 -fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=undefined \
             -fno-omit-frame-pointer -DVB_LIBFUZZER -Wno-unknown-warning-option
  LDSAN    = -fsanitize=fuzzer,address,undefined
  BUILD    = build-fuzz
  BIN      = build-fuzz/bin
endif
CFLAGS   ?=
CFLAGS   += $(CFLAGS_COMMON) $(OPT)
LDLIBS_CORE = -lembree3 -lOpenEXRCore -lpng16 -lstb -lcjson -lexpat -ljpeg -lz -lm -lpthread
LDLIBS_NET  = -lzmq -lsodium
LDLIBS_CHECK = -lcheck -lsubunit -lrt -lm -lpthread

CORE_SRC  = $(wildcard common/*.c)
CORE_OBJ  = $(CORE_SRC:%.c=$(BUILD)/%.o)
CORE_LIB  = $(BUILD)/libvbcore.a

NET_SRC   = $(wildcard proto/*.c) $(filter-out master/main.c,$(wildcard master/*.c)) \
            $(filter-out worker/main.c,$(wildcard worker/*.c))
NET_OBJ   = $(NET_SRC:%.c=$(BUILD)/%.o)
NET_LIB   = $(BUILD)/libvbnet.a
DAEMONS   = $(if $(wildcard master/main.c),$(BIN)/vbrender-master) \
            $(if $(wildcard worker/main.c),$(BIN)/vbrender-worker)

CLIENT_SRC = $(wildcard client/*.c)
# The dashboard's pages (client/web/) become C strings in a generated file.
WEB_ASSETS = $(sort $(wildcard client/web/*))
ASSETS_C   = $(BUILD)/gen/serve_assets.c
ASSETS_OBJ = $(ASSETS_C:.c=.o)
CLIENT_OBJ = $(CLIENT_SRC:%.c=$(BUILD)/%.o) $(ASSETS_OBJ)
LDLIBS_HTTP = -lmicrohttpd

TEST_SRC  = $(wildcard tests/test_*.c)
TEST_BIN  = $(TEST_SRC:tests/%.c=$(BUILD)/tests/%)
TEST_HELPER_SRC = tests/testutil.c
TEST_HELPER_OBJ = $(TEST_HELPER_SRC:%.c=$(BUILD)/%.o)
FUZZ_SRC  = $(wildcard tests/fuzz_*.c)
FUZZ_BIN  = $(FUZZ_SRC:tests/%.c=$(BUILD)/tests/%)
FUZZ_TARGETS = $(FUZZ_SRC:tests/%.c=%)
SEEDS_BIN = $(BUILD)/tests/gen_fuzz_seeds

BENCH_SRC = $(wildcard bench/*.c)
BENCH_BIN = $(BENCH_SRC:bench/%.c=$(BUILD)/bench/%)

# Keep intermediate objects: deleting them only forces rebuilds.
.SECONDARY:

.PHONY: format format-check all deps check test test-browser test-asan test-tsan tsan-run demo bench bench-error clean fuzz fuzz-short fuzz-build fuzz-seeds
all: $(BIN)/vbrender $(DAEMONS) $(CORE_LIB) $(NET_LIB)

deps:
	@missing=""; for p in $(DEB_PACKAGES); do \
	  dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q '^install ok installed' || missing="$$missing $$p"; \
	done; \
	if [ -n "$$missing" ]; then \
	  echo "make deps: installing$$missing"; \
	  $(SUDO) apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends $$missing; \
	else echo "make deps: all packages present"; fi


# Style is enforced, not suggested: .ci/run fails on any difference.
FORMAT_FILES = $(shell git ls-files '*.c' '*.h' 2>/dev/null)
format: deps
	clang-format -i $(FORMAT_FILES)
format-check: deps
	@clang-format --dry-run --Werror $(FORMAT_FILES) && echo "format-check: $(words $(FORMAT_FILES)) files match .clang-format"

$(BUILD)/%.o: %.c
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -c $< -o $@

$(CORE_LIB): $(CORE_OBJ)
	@mkdir -p $(dir $@)
	rm -f $@ && ar rcs $@ $^

$(NET_LIB): $(NET_OBJ)
	@mkdir -p $(dir $@)
	rm -f $@ && ar rcs $@ $^

# Link order: the network library uses the core.
LIBS_ALL = $(NET_LIB) $(CORE_LIB)
LDLIBS_ALL = $(LDLIBS_NET) $(LDLIBS_CORE)

$(BIN)/vbrender: $(CLIENT_OBJ) $(LIBS_ALL)
	@mkdir -p $(dir $@)
	$(CC) $(LDSAN) -pthread -o $@ $(CLIENT_OBJ) $(LIBS_ALL) $(LDLIBS_HTTP) $(LDLIBS_ALL)

# Each file of client/web/ as `const char serve_asset_NAME_EXT[]` (serve.h),
# a line a string: backslashes and quotes escaped, and every ? too, so that
# no "??x" in a page reads as a C trigraph.
$(ASSETS_C): $(WEB_ASSETS) Makefile
	@mkdir -p $(dir $@)
	@{ echo '/* generated from client/web/ by the Makefile: do not edit */'; \
	   for f in $(WEB_ASSETS); do \
	     echo "const char serve_asset_$$(basename $$f | tr '.-' '__')[] ="; \
	     sed -e 's/\\/\\\\/g' -e 's/"/\\"/g' -e 's/?/\\?/g' -e 's/^/    "/' -e 's/$$/\\n"/' $$f; \
	     echo '    "";'; \
	   done; } > $@.tmp && mv $@.tmp $@
$(ASSETS_OBJ): $(ASSETS_C)
	$(CC) $(CFLAGS) -c $< -o $@

# The handlers' unit tests and the integration test link the dashboard's
# code itself (the other suites drive the binaries).
SERVE_OBJ = $(BUILD)/client/serve.o $(BUILD)/client/control.o $(ASSETS_OBJ)
$(BUILD)/tests/test_serve.o: CFLAGS += -Iclient
# The diffuse kernel's AVX2 and AVX-512 builds (common/wave_diffuse_avx2.c,
# wave_diffuse_avx512.c; the tracer picks one only where the host has it):
# flags, which GCC and clang (the fuzz build) both take, where a target
# pragma is GCC's alone.
$(BUILD)/common/wave_diffuse_avx2.o: CFLAGS += -mavx2
$(BUILD)/common/wave_diffuse_avx512.o: CFLAGS += -mavx512f -mavx512vl
$(BUILD)/tests/test_serve: $(BUILD)/tests/test_serve.o $(TEST_HELPER_OBJ) $(SERVE_OBJ) $(LIBS_ALL)
	$(CC) $(LDSAN) -pthread -o $@ $^ $(LDLIBS_CHECK) $(LDLIBS_HTTP) $(LDLIBS_ALL)

$(BIN)/vbrender-%: $(BUILD)/%/main.o $(LIBS_ALL)
	@mkdir -p $(dir $@)
	$(CC) $(LDSAN) -pthread -o $@ $^ $(LDLIBS_ALL)

$(BUILD)/tests/test_%: $(BUILD)/tests/test_%.o $(TEST_HELPER_OBJ) $(LIBS_ALL)
	$(CC) $(LDSAN) -pthread -o $@ $^ $(LDLIBS_CHECK) $(LDLIBS_ALL)

ifeq ($(FUZZ),1)
FUZZ_DRIVER =
else
FUZZ_DRIVER = $(BUILD)/tests/fuzzdriver.o
endif
$(BUILD)/tests/fuzz_%: $(BUILD)/tests/fuzz_%.o $(FUZZ_DRIVER) $(LIBS_ALL)
	$(CC) $(LDSAN) -pthread -o $@ $^ $(LDLIBS_ALL)

$(SEEDS_BIN): $(BUILD)/tests/gen_fuzz_seeds.o $(LIBS_ALL)
	$(CC) $(LDSAN) -pthread -o $@ $^ $(LDLIBS_ALL)

# The master with its fault-injection points compiled in (tests only): the
# same objects, persist.c built with VB_FAULT_INJECTION and linked first, so
# the library's own persist.o is not pulled in.
FAULT_MASTER = $(BUILD)/tests/vbrender-master-fault
$(BUILD)/tests/persist-fault.o: master/persist.c
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -DVB_FAULT_INJECTION -c $< -o $@
$(FAULT_MASTER): $(BUILD)/master/main.o $(BUILD)/tests/persist-fault.o $(LIBS_ALL)
	$(CC) $(LDSAN) -pthread -o $@ $^ $(LDLIBS_ALL)

# The worker likewise (worker.c with VB_FAULT_INJECTION linked first): with
# VB_FAULT_LIE_EVERY=N it perturbs one result in N, for the verification
# tests.
FAULT_WORKER = $(BUILD)/tests/vbrender-worker-fault
$(BUILD)/tests/worker-fault.o: worker/worker.c
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -DVB_FAULT_INJECTION -c $< -o $@
$(FAULT_WORKER): $(BUILD)/worker/main.o $(BUILD)/tests/worker-fault.o $(LIBS_ALL)
	$(CC) $(LDSAN) -pthread -o $@ $^ $(LDLIBS_ALL)

$(BUILD)/bench/%: $(BUILD)/bench/%.o $(LIBS_ALL)
	$(CC) $(LDSAN) -pthread -o $@ $^ $(LDLIBS_ALL)

# Tests find the binary under test and the shared data through these.
TEST_ENV = VB_BIN=$(abspath $(BIN)/vbrender) VB_BINDIR=$(abspath $(BIN)) VB_ROOT=$(CURDIR) \
           VB_FAULT_MASTER=$(abspath $(FAULT_MASTER)) VB_FAULT_WORKER=$(abspath $(FAULT_WORKER)) \
           VB_SHARED=$(abspath ../shared)
# Under the sanitizers each suite runs in one process (no fork per test), so
# LeakSanitizer checks the whole run at exit.
ifeq ($(SAN),1)
  TEST_ENV += CK_FORK=no
endif

# Suites run TEST_JOBS at a time (tests/run-suites.sh -j), test_cluster's
# cases each in a process of its own (test_cluster:*); the builds of `make
# check` use as many jobs. The tests wait for events, not for times, so a
# loaded host makes them slower, not wrong.
TEST_JOBS ?= $(shell nproc 2>/dev/null || echo 2)
TEST_RUN   = $(filter-out %/test_cluster,$(TEST_BIN)) '$(BUILD)/tests/test_cluster:*'

# Mutations per fuzz target in `make test` (the standalone driver, fixed
# seed). Every target does 20000 in under 4 s under ASan; one that gets
# slow can have fewer, as FUZZ_N_fuzz_NAME = N.
FUZZ_N    = 20000
# (fuzz_mitsuba writes each input to a file and reads what it names)
FUZZ_N_fuzz_mitsuba = 3000
FUZZ_RUNS = $(foreach f,$(FUZZ_BIN),$(f):$(or $(FUZZ_N_$(notdir $(f))),$(FUZZ_N)))

# (the benchmarks are built too, not run: a change to an API they call
# must not leave `make bench` broken until someone next runs it)
test: $(BIN)/vbrender $(DAEMONS) $(TEST_BIN) $(FUZZ_BIN) $(FAULT_MASTER) $(FAULT_WORKER) $(SEEDS_BIN) \
      $(BENCH_BIN)
	@tests/check-docs.sh
	@mkdir -p $(BUILD)/test-out
	@TMPDIR=$(abspath $(BUILD)/test-out) $(SEEDS_BIN) --check tests/data
	@$(TEST_ENV) VB_TMP=$(abspath $(BUILD)/test-out) tests/run-suites.sh -j $(TEST_JOBS) \
	  $(TEST_RUN) -- $(FUZZ_RUNS)

test-asan:
	$(MAKE) SAN=1 test

# ---- ThreadSanitizer: make test-tsan ----------------------------------------
# Only what runs on several threads; the rest is single-threaded and would
# add time and nothing else. test_tracer's "determinism" case: render_run's
# threads (common/render.c) at 1, 2 and 3 threads over several layers (its
# other cases are the same threads on other scenes); test_cli and
# test_adaptive: the embedded render (master and workers in threads of
# `vbrender render`); test_cluster: real master and worker daemons (TSan
# builds too: VB_BINDIR is this tree's), three of its cases; test_serve's
# live case: `vbrender serve`'s HTTP threads sharing one control connection,
# under concurrent requests. SUITE:CASE runs
# one Check case (tests/run-suites.sh). A report makes the process exit 66,
# which fails the test; reports also go to files (log_path), so that one in
# a process the test kills on purpose (kill -9 of a worker) or in a timed
# out client fails the run too, and they are printed at the end.
# tests/tsan.supp says what is left out and why (third-party libraries
# only). atexit_sleep_ms=0: TSan otherwise sleeps 1 s in every exiting
# process, and every test, client run and daemon is one; all our threads are
# joined before exit, so the sleep would catch nothing.
TSAN_CLUSTER_CASES = identical_pixels worker_killed sigterm worker_before_master
TSAN_TESTS = $(addprefix $(BUILD)/tests/,test_tracer test_cli test_adaptive test_cluster test_serve)
TSAN_RUN   = $(BUILD)/tests/test_tracer:determinism $(BUILD)/tests/test_cli $(BUILD)/tests/test_adaptive \
             $(addprefix $(BUILD)/tests/test_cluster:,$(TSAN_CLUSTER_CASES)) $(BUILD)/tests/test_serve:live

test-tsan:
	$(MAKE) SAN=thread tsan-run

tsan-run: $(BIN)/vbrender $(DAEMONS) $(TSAN_TESTS)
	@[ "$(SAN)" = thread ] || { echo "tsan-run needs SAN=thread: run make test-tsan"; exit 2; }
	@mkdir -p $(BUILD)/test-out
	@rm -f $(BUILD)/test-out/tsan-report.*
	@$(TEST_ENV) VB_TMP=$(abspath $(BUILD)/test-out) \
	  TSAN_OPTIONS="suppressions=$(CURDIR)/tests/tsan.supp atexit_sleep_ms=0 second_deadlock_stack=1 \
	                log_path=$(abspath $(BUILD)/test-out/tsan-report) $$TSAN_OPTIONS" \
	  tests/run-suites.sh -j $(TEST_JOBS) $(TSAN_RUN); rc=$$?; \
	for f in $(BUILD)/test-out/tsan-report.*; do \
	  [ -e "$$f" ] || continue; echo "== ThreadSanitizer: $$f"; cat "$$f"; rc=1; \
	done; exit $$rc

# The dashboard in headless Chromium against real daemons; its screenshots
# stay in $(BUILD)/test-artifacts/.
test-browser: $(BIN)/vbrender $(DAEMONS)
	VB_BINDIR=$(abspath $(BIN)) VB_ARTIFACTS=$(abspath $(BUILD))/test-artifacts \
	  tests/browser/test_dashboard.sh

check: deps
	$(MAKE) -j$(TEST_JOBS) all
	$(MAKE) -j$(TEST_JOBS) test
	$(MAKE) test-browser
	$(MAKE) -j$(TEST_JOBS) test-asan
	$(MAKE) -j$(TEST_JOBS) test-tsan
	$(MAKE) -j$(TEST_JOBS) fuzz-short

# The seed corpora the project's own writers make (tests/gen_fuzz_seeds.c);
# `make test` checks that the committed ones are still what they make.
fuzz-seeds: $(SEEDS_BIN)
	$(SEEDS_BIN) tests/data

# Under FUZZ=1: the libFuzzer binaries, build-fuzz/tests/fuzz_*.
fuzz-build: $(FUZZ_BIN)

# Each target for 1,000,000 runs, one after another, on a scratch copy of
# its corpus (tests/data/fuzz-NAME); a table of runs, seconds and findings;
# fails on any finding (kept in build-fuzz/findings/).
fuzz: deps
	$(MAKE) FUZZ=1 fuzz-build
	tests/run-libfuzzer.sh build-fuzz/tests 1000000 0 $(FUZZ_TARGETS)

# CI's short pass: each target for 20,000 runs or 10 s, whichever comes
# first; skipped where clang cannot link libFuzzer.
fuzz-short:
	@if tests/run-libfuzzer.sh --available; then \
	  $(MAKE) FUZZ=1 fuzz-build && tests/run-libfuzzer.sh build-fuzz/tests 20000 10 $(FUZZ_TARGETS); \
	else echo "fuzz-short: skipped (no clang with libFuzzer; make deps installs it)"; fi

demo: deps
	$(MAKE) all
	@mkdir -p out
	$(BIN)/vbrender render scenes/cornell-box.json -o out/cornell-box.exr

bench: deps
	$(MAKE) all $(BENCH_BIN) $(FAULT_WORKER)
	bench/run-core.sh
	if [ -x bench/run-distributed.sh ]; then bench/run-distributed.sh; fi
	bench/run-durable.sh
	bench/run-verify.sh
	bench/run-stragglers.sh
	bench/run-curve.sh
	bench/run-preview.sh

bench-error: deps
	$(MAKE) all $(BUILD)/bench/bench_batches
	bash bench/run-sampler.sh
	bash bench/error/run.sh
	bash bench/error/run.sh --repeat
	bash bench/error/run.sh --calibrate
	bash bench/error/run.sh --coverage
	bash bench/error/run.sh --peer-best
	bash bench/mitsuba-scenes/run.sh

clean:
	rm -rf build build-asan build-tsan build-fuzz bin

-include $(CORE_OBJ:.o=.d) $(NET_OBJ:.o=.d) $(CLIENT_OBJ:.o=.d) $(BUILD)/master/main.d $(BUILD)/worker/main.d $(TEST_BIN:=.d) $(TEST_HELPER_OBJ:.o=.d) \
         $(FUZZ_BIN:=.d) $(BUILD)/tests/fuzzdriver.d $(BENCH_BIN:=.d) $(BUILD)/tests/persist-fault.d \
         $(BUILD)/tests/worker-fault.d $(SEEDS_BIN).d
