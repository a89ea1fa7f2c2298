# nimbus: `make demo` renders the bundled scenes, `make test` runs every test.
# Both install the Debian packages they need first (scripts/install-deps.sh, as root).

CARGO ?= cargo
# `make build`, `demo` and `bench` use the release profile (thin LTO); `make test` builds
# everything once with the `ci` profile (optimised, no LTO) and all tests share that build.
RELEASE := --release --locked
TEST_PROFILE := --profile ci --locked

.PHONY: all deps build test demo bench dist clean

all: build

deps:
	@scripts/install-deps.sh

build: deps
	$(CARGO) build $(RELEASE) --workspace --bins

# The binaries first: `cargo test` links only the root package's (tests/dist.rs packs them all).
test: deps
	$(CARGO) build $(TEST_PROFILE) --workspace --bins --examples
	$(CARGO) test $(TEST_PROFILE) --workspace --no-fail-fast

demo: build
	scripts/demo.sh

bench: build
	scripts/bench.sh

# dist/nimbus-VERSION-linux-x86_64.tar.xz: the tools and the libraries they need (scripts/dist.sh).
dist: build
	$(CARGO) build $(RELEASE) -p nimbus-density --example gen_particles
	scripts/dist.sh target/release dist

clean:
	$(CARGO) clean
	rm -rf out dist
