# Source me (bash):  source env.sh
# Activates the project's venv (which is also the ROS 2 Jazzy prefix) and the
# colcon-built workspace; afterwards every rths executable is on PATH:
# rths, numerical_node, compensator_node, bridge_node, recorder.
_rths_root="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
if [ ! -f "$_rths_root/install/setup.bash" ]; then
  echo "env.sh: the workspace is not built yet; run 'make setup' first" >&2
  return 1 2>/dev/null || exit 1
fi
# shellcheck disable=SC1091
source "$_rths_root/.venv/bin/activate"
case ":${AMENT_PREFIX_PATH:-}:" in *":$VIRTUAL_ENV:"*) ;; *)
  export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}";; esac
case ":${CMAKE_PREFIX_PATH:-}:" in *":$VIRTUAL_ENV:"*) ;; *)
  export CMAKE_PREFIX_PATH="$VIRTUAL_ENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}";; esac
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
# Talk only on this host unless the operator opens the graph to a lab network (README).
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
# shellcheck disable=SC1091
source "$_rths_root/install/setup.bash"
for _rths_bin in "$_rths_root"/install/*/lib/rths_*; do
  case ":$PATH:" in *":$_rths_bin:"*) ;; *) [ -d "$_rths_bin" ] && PATH="$_rths_bin:$PATH";; esac
done
export PATH
export RTHS_ROOT="$_rths_root"
unset _rths_root _rths_bin
