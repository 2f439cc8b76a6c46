#!/usr/bin/env bash
# Run launch/pepper.launch.py for real with the launch stack of ../shared/tools/ros2-launch-stack
# and check model path precedence, booleans, names, errors, respawn and signals
# (support/launch_check.py prints one line per check).
# support/launch_test.sh runs test/test_launch_pepper.py under launch_testing the same way.
#   support/launch_check.sh [defaults|model_path|names|errors|respawn|signals ...]
# Environment: LAUNCHCHECK (stack build dir), ROS_DOMAIN_ID (your own), LAUNCH_CHECK_LOGS.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
STACK=../shared/tools/ros2-launch-stack
"$STACK/setup.sh" >/dev/null
# shellcheck disable=SC1091
source "$STACK/env.sh"
exec python support/launch_check.py "$@"
