# Source me: puts the project venv and the built vibro_msgs on the paths (bash or sh).
# Usage: . scripts/env.sh
VIBRO_ROOT="${VIBRO_ROOT:-$(cd "$(dirname "${BASH_SOURCE:-$0}")/.." && pwd)}"
export VIBRO_ROOT
VIBRO_INSTALL="$VIBRO_ROOT/install"
export PATH="$VIBRO_ROOT/.venv/bin:$PATH"
export AMENT_PREFIX_PATH="$VIBRO_INSTALL:$VIBRO_ROOT/.venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export LD_LIBRARY_PATH="$VIBRO_INSTALL/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
export PYTHONPATH="$VIBRO_INSTALL/lib/python3.11/site-packages${PYTHONPATH:+:$PYTHONPATH}"
# Keep DDS traffic on this machine unless the user chose otherwise.
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
