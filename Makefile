# raylab: `make run` and `make test` install what is missing, build and run.
# Debian packages are installed with apt-get (through sudo when not root).

CARGO ?= cargo
# fonts-dejavu-core: the TrueType font the bench's charts write their text with.
DEB_PACKAGES := build-essential pkg-config libclang-dev libembree-dev fonts-dejavu-core
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
RAYLAB := target/release/raylab

.PHONY: deps browser real-scenes sponza sponza-path sponza-view build run test bench bench-quick criterion lint clean

deps:
	@missing=""; \
	for p in $(DEB_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:$$missing"; \
	  $(SUDO) apt-get update -qq && \
	  $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; \
	fi
	@command -v $(CARGO) >/dev/null || { echo "cargo not found: install Rust (https://rustup.rs)"; exit 1; }

# Headless Chromium, with which the tests open the bench's HTML report (CI installs it).
browser:
	@command -v chromium >/dev/null || { \
	  echo "installing Debian package: chromium"; \
	  $(SUDO) apt-get update -qq && \
	  $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; }

# Real exported scenes to try raylab on (OBJ from Blender and others, PLY, glTF
# 2.0: assimp's test models, in /usr/share/assimp/models); CI renders and
# validates some of them.
real-scenes:
	@dpkg -s assimp-testmodels >/dev/null 2>&1 || { \
	  echo "installing Debian package: assimp-testmodels"; \
	  $(SUDO) apt-get update -qq && \
	  $(SUDO) env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq assimp-testmodels; }

# A real architecture scene: Marko Dabrovic's Sponza atrium (66,450 triangles:
# arcades, columns, long thin walls), which the bvh crate ships in its sources
# (media/sponza.obj; cargo fetches it with raylab's dependencies). Its path,
# and a render from inside, where its structure is seen.
SPONZA = $(shell $(CARGO) metadata --format-version 1 2>/dev/null | python3 -c \
  'import json,sys,os; d=json.load(sys.stdin); print(next(os.path.join(os.path.dirname(p["manifest_path"]),"media","sponza.obj") for p in d["packages"] if p["name"]=="bvh"))' 2>/dev/null)
SPONZA_VIEW := --eye=-14,2,0 --look 10,5,0 --fov 70

# Only the path on stdout (scripts capture it): no package check here, and
# one recipe line: $(SPONZA) runs cargo metadata each time it is expanded.
sponza-path:
	@p="$(SPONZA)"; test -f "$$p" || { echo "sponza.obj not found in the bvh crate's sources (run cargo fetch)" >&2; exit 1; }; echo "$$p"

# The view from inside, for scripts (CI renders and validates from it).
sponza-view:
	@echo "$(SPONZA_VIEW)"

sponza: build sponza-path
	$(RAYLAB) render "$(SPONZA)" $(SPONZA_VIEW) -o sponza.png

build: deps
	$(CARGO) build --release

# Renders the built-in default scene (cornell-original, 1024x768, paper AO) and prints timings.
run: build
	$(RAYLAB) render -o out.png

test: deps
	$(CARGO) test --release --all-targets

# The full bench (10 reps, 1024x768, AO off and paper; about an hour on 2 cores):
# tables, charts and bench-report/index.html.
bench: build
	$(RAYLAB) bench --out bench-report

# The same in under a minute, with small images and one rep.
bench-quick: build
	$(RAYLAB) bench --quick --out bench-report

# criterion benches of the kernels (ray/box, ray/triangle, traversal, builds).
criterion: deps
	$(CARGO) bench

lint:
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --all-targets -- -D warnings

clean:
	$(CARGO) clean
