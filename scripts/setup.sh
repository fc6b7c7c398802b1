#!/usr/bin/env bash
# Installs exactly the Debian 12 packages haze needs. Idempotent; root or sudo.
set -euo pipefail

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi

PACKAGES=(
  # toolchain
  build-essential clang cmake ninja-build pkg-config clang-format
  # volumes
  libopenvdb-dev libnanovdb-dev libtbb-dev libboost-iostreams-dev liblog4cplus-dev libblosc-dev zlib1g-dev
  # surfaces
  libembree-dev libtinyobjloader-dev libstb-dev
  # Vulkan: loader, headers, validation, shader compiler (glslangValidator, and the library for run-time compiles)
  libvulkan-dev vulkan-validationlayers glslang-tools glslang-dev spirv-tools
  # math, images, CLI, formats, logging
  libglm-dev libopenexr-dev libcli11-dev nlohmann-json3-dev libfmt-dev
  # tests and benchmarks
  libgtest-dev
  # `haze report`: figures (matplotlib), and the test that opens the report in headless Chromium
  python3-matplotlib python3-numpy chromium
  # `haze view`: the window (GLFW on X11), Dear ImGui with its GLFW and Vulkan backends, and the X server
  # the viewer's tests run it under (xvfb-run)
  libglfw3-dev libimgui-dev xvfb xauth
)

BACKPORTS=/etc/apt/sources.list.d/haze-bookworm-backports.list
need_update=0
if ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
  echo "deb http://deb.debian.org/debian bookworm-backports main" | $SUDO tee "$BACKPORTS" >/dev/null
  need_update=1
fi

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done

# lavapipe >= 24 (Mesa 25 from bookworm-backports): Mesa 22.3 silently cuts long loops.
mesa_ok=0
v=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)
if [ -n "$v" ] && dpkg --compare-versions "$v" ge 24; then mesa_ok=1; fi

if [ ${#missing[@]} -eq 0 ] && [ $mesa_ok -eq 1 ]; then
  echo "setup: all packages present (mesa-vulkan-drivers $v)"
  exit 0
fi

export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
if [ ${#missing[@]} -gt 0 ]; then
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
if [ $mesa_ok -eq 0 ]; then
  $SUDO apt-get install -y -qq --no-install-recommends -t bookworm-backports mesa-vulkan-drivers
fi
echo "setup: done (mesa-vulkan-drivers $(dpkg-query -W -f='${Version}' mesa-vulkan-drivers))"
