#!/usr/bin/env bash
# Build and install vibro_msgs (ament_cmake + rosidl) against the ROS 2 Jazzy wheels in .venv.
# Idempotent: skips the build when the .msg files and CMakeLists are unchanged since the last install.
# See ../shared/ros-from-pypi.md (docs/ros-from-pypi-notes.md) for why each step is here.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
PY="$VENV/bin/python"
PKG="$ROOT/src/vibro_msgs"
BUILD="$ROOT/build/vibro_msgs"
INSTALL="$ROOT/install"
STAMP="$INSTALL/.vibro_msgs.stamp"

hash_now=$(cat "$PKG"/CMakeLists.txt "$PKG"/package.xml "$PKG"/msg/*.msg | sha256sum | cut -d' ' -f1)
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$hash_now" ] \
   && [ -d "$INSTALL/lib/python3.11/site-packages/vibro_msgs" ]; then
  echo "vibro_msgs: up to date"
  exit 0
fi

# The message wheels' exported CMake files name the include paths of the machine that
# built them; point them at this interpreter's and numpy's (inside the venv only).
py_inc=$("$PY" -c "import sysconfig; print(sysconfig.get_paths()['include'])")
np_inc=$("$PY" -c "import numpy; print(numpy.get_include())")
{ grep -l "/opt/python/cp311-cp311" "$VENV"/share/*/cmake/*.cmake 2>/dev/null || true; } | while read -r f; do
  sed -i -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$np_inc#g" \
         -e "s#/opt/python/cp311-cp311/include/python3.11#$py_inc#g" "$f"
done

export AMENT_PREFIX_PATH="$VENV"
export CMAKE_PREFIX_PATH="$VENV;$VENV/lib/python3.11/site-packages"
export PATH="$VENV/bin:$PATH"
rm -rf "$BUILD"
mkdir -p "$BUILD"
echo "vibro_msgs: building (cmake) ..."
cmake -S "$PKG" -B "$BUILD" -DCMAKE_INSTALL_PREFIX="$INSTALL" -DPython3_EXECUTABLE="$PY" \
      -DBUILD_TESTING=OFF -DCMAKE_BUILD_TYPE=Release > "$BUILD/cmake.log" 2>&1 \
  || { tail -40 "$BUILD/cmake.log"; exit 1; }
cmake --build "$BUILD" -j2 > "$BUILD/build.log" 2>&1 || { tail -40 "$BUILD/build.log"; exit 1; }
cmake --install "$BUILD" > "$BUILD/install.log" 2>&1 || { tail -40 "$BUILD/install.log"; exit 1; }
echo "$hash_now" > "$STAMP"
echo "vibro_msgs: installed in $INSTALL"
