#!/usr/bin/env bash
# Run test/test_launch_pepper.py under launch_testing on a machine without a ROS distro: on top of
# the launch stack of ../shared/tools/ros2-launch-stack, build launch_testing from the same
# ros2/launch mirror into $LAUNCHCHECK/launch_testing, and give the stack's venv a pytest < 9
# (launch_testing's pytest plugin of 2024 declares a `path` hook argument that pytest 9 removed).
#   support/launch_test.sh [pytest options]
# Environment: LAUNCHCHECK (stack build dir), ROS_DOMAIN_ID (your own), MIRRORS, ROS_BRANCH (as
# setup.sh; launch_testing is taken from the same branch, default rolling).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
STACK=../shared/tools/ros2-launch-stack
"$STACK/setup.sh" >/dev/null
LAUNCHCHECK="${LAUNCHCHECK:-/tmp/launchcheck}"
MIRRORS="${MIRRORS:-$(cd ../.mirror && pwd)}"
LT="$LAUNCHCHECK/launch_testing"
# shellcheck disable=SC1091
source "$STACK/env.sh" >/dev/null
if [[ ! -f "$LT/install/local_setup.sh" ]]; then
  rm -rf "$LT"; mkdir -p "$LT/src"
  git --git-dir="$MIRRORS/ros2+launch/repo" archive "${ROS_BRANCH:-rolling}" launch_testing | tar -x -C "$LT/src"
  (cd "$LT" && COLCON_HOME="$LT/colcon_home" colcon --log-base log build --merge-install \
     --base-paths src --install-base install >"$LT/build.log" 2>&1) \
    || { tail -20 "$LT/build.log" >&2; exit 1; }
  python -m pip install -q "pytest>=8.3,<9"
fi
set +u
# shellcheck disable=SC1091
source "$LT/install/local_setup.sh"
set -u
exec python -m pytest test/test_launch_pepper.py -p no:cacheprovider "$@"
