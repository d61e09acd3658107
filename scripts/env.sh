# Source me (bash): the environment every motion_ctrl process runs in.
# Used by scripts/demo and scripts/test; `source scripts/env.sh` in a shell
# makes .venv's ros2-less ROS 2 usable by hand too.
_mc_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"

# Network hygiene: DDS discovery stays on this host (ROS_LOCALHOST_ONLY is
# ignored by Kilted), and each run gets its own domain unless one is chosen.
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
if [[ -z "${ROS_DOMAIN_ID:-}" || "${ROS_DOMAIN_ID}" == 0 ]]; then
    # 1..101: above 101 the DDS ports of a domain reach into Linux's ephemeral
    # port range (32768+), where they can collide with client sockets.
    export ROS_DOMAIN_ID=$(( $$ % 101 + 1 ))
fi

export AMENT_PREFIX_PATH="$_mc_root/.venv"
export RMW_IMPLEMENTATION=rmw_fastrtps_cpp
export PATH="$_mc_root/.venv/bin:$PATH"
unset _mc_root
