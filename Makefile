# nimbus: `make demo` renders the bundled scenes, `make test` runs every test.
# Both install the Debian packages they need first (scripts/install-deps.sh, as root).

CARGO ?= cargo
# `make build`, `demo` and `bench` use the release profile (thin LTO); `make test` builds
# everything once with the `ci` profile (optimised, no LTO) and all tests share that build.
RELEASE := --release --locked
TEST_PROFILE := --profile ci --locked

.PHONY: all deps build test demo bench clean

all: build

deps:
	@scripts/install-deps.sh

build: deps
	$(CARGO) build $(RELEASE) --workspace --bins

test: deps
	$(CARGO) test $(TEST_PROFILE) --workspace --no-fail-fast

demo: build
	scripts/demo.sh

bench: build
	scripts/bench.sh

clean:
	$(CARGO) clean
	rm -rf out
