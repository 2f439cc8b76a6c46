#!/usr/bin/env bash
# Run launch/pepper.launch.py for real with the launch stack of ../shared/tools/ros2-launch-stack
# and check model path precedence, booleans, names, errors, respawn and signals
# (support/launch_check.py prints one line per check).
# support/launch_test.sh runs test/test_launch_pepper.py under launch_testing the same way.
#   support/launch_check.sh [defaults|model_path|names|errors|respawn|signals ...]
#   VENV=.venv-jazzy support/launch_check.sh          (on Jazzy's wheels: make setup ROS_DISTRO=jazzy)
# Environment: VENV (the venv whose ROS 2 wheels the stack is built on: .venv, Kilted's, by default),
# LAUNCHCHECK (stack build dir; default /tmp/launchcheck, /tmp/launchcheck-jazzy for .venv-jazzy),
# LAUNCH_STACK (the stack's folder), ROS_DOMAIN_ID (your own), LAUNCH_CHECK_LOGS.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
STACK="${LAUNCH_STACK:-../shared/tools/ros2-launch-stack}"
VENV="${VENV:-.venv}"
export LAUNCHCHECK="${LAUNCHCHECK:-/tmp/launchcheck${VENV#.venv}}"
PROJECT=.
if [[ "$(cd "$VENV" && pwd)" != "$PWD/.venv" ]]; then
  # The stack's setup.sh builds on a checkout's own .venv: give it a copy of this checkout's files
  # (tracked and untracked, not ignored, and the console's built page) whose .venv is $VENV.
  # Copies keep their times, so the stack rebuilds its overlay only when a file changed.
  PROJECT="$LAUNCHCHECK/checkout"
  venv_dir="$(cd "$VENV" && pwd)"
  rm -rf "$PROJECT" && mkdir -p "$PROJECT"
  { git ls-files -co --exclude-standard -z && find web/dist -type f -print0 2>/dev/null; } \
    | tar --null --ignore-failed-read -T - -cf - | tar -xf - -C "$PROJECT"
  ln -s "$venv_dir" "$PROJECT/.venv"
fi
"$STACK/setup.sh" "$PROJECT" >/dev/null
# shellcheck disable=SC1091
source "$STACK/env.sh"
exec python support/launch_check.py "$@"
