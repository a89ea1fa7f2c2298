# nimbus: `make demo` renders the bundled scenes, `make test` runs every test.
# Both install the Debian packages they need first (scripts/install-deps.sh, as root).

CARGO ?= cargo
# One release build serves the tools, the tests and the benchmarks.
RELEASE := --release --locked
BIN := target/release

.PHONY: all deps build test demo bench clean

all: build

deps:
	@scripts/install-deps.sh

build: deps
	$(CARGO) build $(RELEASE) --workspace --bins

test: deps
	$(CARGO) test $(RELEASE) --workspace --no-fail-fast

demo: build
	scripts/demo.sh

bench: build
	scripts/bench.sh

clean:
	$(CARGO) clean
	rm -rf out
