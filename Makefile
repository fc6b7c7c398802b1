# Entry points of the README. Each target runs the project's setup script first (idempotent).
BUILD ?= build
JOBS ?= $(shell nproc)

.PHONY: setup configure build demo demo-assets smoke test bench clean

setup:
	bash scripts/setup.sh

configure: setup
	cmake -S . -B $(BUILD) -G Ninja -DCMAKE_BUILD_TYPE=Release

build: configure
	cmake --build $(BUILD) -j $(JOBS)

demo: build
	MESA_SHADER_CACHE_DIR=$(CURDIR)/$(BUILD)/mesa-cache $(BUILD)/haze render scenes/demo.json --out out/demo
	MESA_SHADER_CACHE_DIR=$(CURDIR)/$(BUILD)/mesa-cache $(BUILD)/haze render scenes/room.json --frames 0:0 --out out/room

# scenes/smoke.json's generated assets (scenes/assets/, not committed): a drifting smoke sequence with its
# velocity and a sky map, written by the project's own generators.
demo-assets: build
	HAZE=$(BUILD)/haze bash scripts/make_demo_assets.sh

smoke: demo-assets
	MESA_SHADER_CACHE_DIR=$(CURDIR)/$(BUILD)/mesa-cache $(BUILD)/haze render scenes/smoke.json --out out/smoke

test: build
	cd $(BUILD) && ctest --output-on-failure -j $(JOBS)

# The viewer's part of the bench needs an X display: a private Xvfb when there is none.
bench: build
	MESA_SHADER_CACHE_DIR=$(CURDIR)/$(BUILD)/mesa-cache $(if $(DISPLAY),,scripts/xvfb.sh) $(BUILD)/haze bench

clean:
	rm -rf $(BUILD) out
