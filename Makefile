# raylab: `make run` and `make test` install what is missing, build and run.
# Debian packages are installed with apt-get (through sudo when not root).

CARGO ?= cargo
DEB_PACKAGES := build-essential pkg-config libclang-dev libembree-dev
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
RAYLAB := target/release/raylab

.PHONY: deps build run test bench lint clean

deps:
	@missing=""; \
	for p in $(DEB_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:$$missing"; \
	  $(SUDO) apt-get update -qq && \
	  $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; \
	fi
	@command -v $(CARGO) >/dev/null || { echo "cargo not found: install Rust (https://rustup.rs)"; exit 1; }

build: deps
	$(CARGO) build --release

# Renders the built-in default scene (cornell-original, 1024x768, paper AO) and prints timings.
run: build
	$(RAYLAB) render -o out.png

test: deps
	$(CARGO) test --release --all-targets

bench: build
	$(CARGO) bench

lint:
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --all-targets -- -D warnings

clean:
	$(CARGO) clean
