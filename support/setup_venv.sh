#!/usr/bin/env bash
# Create or update one of the project's virtual environments, as run by `make setup`:
#   support/setup_venv.sh [kilted|jazzy]      (default kilted)
# kilted -> .venv with ROS 2 Kilted's wheels (support/requirements.txt); jazzy -> .venv-jazzy with
# the same requirements, except that its ROS wheels (every `ros-` line of requirements.txt) are
# Jazzy's, pinned in support/requirements-jazzy.txt. The steps, for either:
#   1. python3 -m venv <venv> (only if missing)
#   2. pip install the requirements (ROS 2 wheels, rosidl toolchain, torch, ...)
#   3. pip install --no-deps --no-build-isolation -e .  (this package, editable)
#   4. rewrite the ROS wheels' exported CMake files that hard-code the wheel builder's Python and
#      numpy include paths (/opt/python/cpXY-cpXY/...) to this venv's own paths
#   5. build support/ros_msgs/{audio_common_msgs,naoqi_bridge_msgs} with plain cmake and install
#      them into the venv, only where one of their messages (every msg/*.msg of the copy, e.g.
#      naoqi_bridge_msgs.msg.AudioBuffer) does not import (a ROS distro provides them via apt)
#   6. Debian tools the tests use (check_urdf from liburdfdom-tools): apt-installed when missing,
#      only as root with apt-get; otherwise the script says what to install (those tests skip)
#   7. verify that rclpy, both message packages, torch, python_speech_features and the rendering
#      stack (pybullet, yourdfpy, imageio-ffmpeg) import
# Before all that, and also when the venv is up to date: the operator console's front end
# (web/: npm ci && npm run build -> web/dist, served by console_node) when its sources changed,
# if node and npm are installed; without them the console serves a page saying it is not built.
# A stamp file in the venv records a hash of the inputs; when nothing changed the script only says so.
# Environment: PYTHON (interpreter used to create the venv, default python3),
#              AUDIO2POSE_SETUP_FORCE=1 (ignore the stamp and redo every step).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
SUPPORT="$ROOT/support"
DISTRO="${1:-kilted}"
MSG_SRC="$SUPPORT/ros_msgs"
MSG_PKGS=(audio_common_msgs naoqi_bridge_msgs)
BOOT_PYTHON="${PYTHON:-python3}"

log() { printf '[setup] %s\n' "$*"; }
die() { printf '[setup] ERROR: %s\n' "$*" >&2; exit 1; }

# The ROS 2 distro whose wheels the venv gets: its folder, and the file that pins its ROS wheels
# in place of requirements.txt's `ros-` lines (Kilted's) for a distro other than Kilted.
case "$DISTRO" in
  kilted) VENV="$ROOT/.venv" DISTRO_REQS=() ;;
  jazzy) VENV="$ROOT/.venv-jazzy" DISTRO_REQS=("$SUPPORT/requirements-jazzy.txt") ;;
  *) die "unknown ROS 2 distro '$DISTRO' (kilted or jazzy)" ;;
esac
VENV_NAME="${VENV#"$ROOT"/}"
STAMP="$VENV/.audio2pose_setup.stamp"
STATE="$VENV/.audio2pose_setup"

# Another venv's ROS bootstrap state must not leak in: the wheels' .pth re-execs the interpreter
# with LD_LIBRARY_PATH pointing at *its* venv unless this guard is already set.
unset _ROS_WHEELS_BOOTSTRAP_COMPLETE PYTHONHOME
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST

cd "$ROOT"

# Hash of files (paths relative to the repo root, so the hash does not depend on where it lives).
hash_files() {
  local f
  for f in "$@"; do
    printf '== %s\n' "${f#"$ROOT"/}"
    if [[ -f "$f" ]]; then cat "$f"; else printf '(missing)\n'; fi
  done | sha256sum | cut -d' ' -f1
}
msg_files() { find "$MSG_SRC/$1" -type f | LC_ALL=C sort; }
# `from <pkg>.msg import A, B`: every message of our copy must import, not only the package.
msg_import() {
  local names
  names="$(find "$MSG_SRC/$1/msg" -name '*.msg' -printf '%f\n' | sed 's/\.msg$//' | LC_ALL=C sort \
    | paste -sd, - | sed 's/,/, /g')"
  printf 'from %s.msg import %s' "$1" "$names"
}

# The console's front end: rebuilt when web/ changed (its own stamp), only where npm exists.
build_console_web() {
  local web="$ROOT/web" stamp="$ROOT/web/dist/.audio2pose_build.sha256" hash
  hash="$(hash_files "$web/package.json" "$web/package-lock.json" "$web/build.mjs" \
    $(find "$web/src" -type f | LC_ALL=C sort))"
  if [[ -f "$stamp" && "$(cat "$stamp")" == "$hash" && -f "$web/dist/index.html" ]]; then
    log "console front end: web/dist is up to date"
  elif command -v npm >/dev/null && command -v node >/dev/null; then
    log "console front end: npm ci && npm run build (web/ -> web/dist)"
    (cd "$web" && npm ci --no-audit --no-fund --loglevel=error && npm run build --silent) \
      || die "building the console's front end failed (cd web && npm ci && npm run build)"
    printf '%s\n' "$hash" >"$stamp"
  else
    log "console front end: WARNING: node/npm not found; the console will serve a page saying" \
      "it is not built (Debian: apt-get install nodejs npm, then make setup)"
  fi
}
build_console_web

mapfile -t ALL_MSG_FILES < <(find "$MSG_SRC" -type f | LC_ALL=C sort)
INPUT_HASH="$(
  {
    hash_files "$SUPPORT/requirements.txt" "${DISTRO_REQS[@]}" "$ROOT/setup.cfg" "$ROOT/setup.py" \
      "$ROOT/pyproject.toml" "$SUPPORT/setup_venv.sh" "${ALL_MSG_FILES[@]}"
    "$BOOT_PYTHON" -c 'import sys; print(sys.version)'
  } | sha256sum | cut -d' ' -f1
)"

if [[ "${AUDIO2POSE_SETUP_FORCE:-0}" != 1 && -x "$VENV/bin/python" && -f "$STAMP" \
      && "$(cat "$STAMP")" == "$INPUT_HASH" ]]; then
  log "$VENV_NAME is up to date (inputs unchanged; AUDIO2POSE_SETUP_FORCE=1 to redo)"
  exit 0
fi

START=$SECONDS

# ---------------------------------------------------------------------------------------------
log "[1/7] virtual environment: $VENV"
if [[ ! -x "$VENV/bin/python" ]]; then
  log "      creating it with $BOOT_PYTHON ($("$BOOT_PYTHON" --version 2>&1))"
  "$BOOT_PYTHON" -m venv "$VENV"
else
  log "      exists"
fi
PY="$VENV/bin/python"
mkdir -p "$STATE"
rm -f "$STAMP"
export VIRTUAL_ENV="$VENV"
export PATH="$VENV/bin:$PATH"

# ---------------------------------------------------------------------------------------------
REQS=(-r "$SUPPORT/requirements.txt")
if (( ${#DISTRO_REQS[@]} )); then
  # requirements.txt without its ROS wheels (the `ros-` lines), then the distro's own
  grep -v '^ros-' "$SUPPORT/requirements.txt" >"$STATE/requirements-without-ros.txt"
  REQS=(-r "$STATE/requirements-without-ros.txt" -r "${DISTRO_REQS[0]}")
fi
log "[2/7] pip install ${REQS[*]#"$ROOT"/} (first run: a few minutes)"
# (pipefail: the pipeline fails iff pip fails; the filter only hides noise)
"$PY" -m pip install --progress-bar off "${REQS[@]}" 2>&1 \
  | { grep -v -E '^(Requirement already satisfied|  Using cached|  Downloading|  Obtaining|WARNING: Location .* is ignored)' || true; } \
  || die "pip install ${REQS[*]#"$ROOT"/} failed"

# ---------------------------------------------------------------------------------------------
log "[3/7] pip install --no-deps --no-build-isolation -e . (audio2pose_ros, editable)"
"$PY" -m pip install --progress-bar off --quiet --no-deps --no-build-isolation -e "$ROOT" \
  || die "editable install of audio2pose_ros failed"

# ---------------------------------------------------------------------------------------------
log "[4/7] pointing the ROS wheels' CMake exports at this venv's Python and numpy headers"
"$PY" - "$VENV" <<'EOF'
import pathlib
import re
import sys
import sysconfig

import numpy

venv = pathlib.Path(sys.argv[1])
py_inc = sysconfig.get_paths()["include"]
np_inc = numpy.get_include()
if not (pathlib.Path(py_inc) / "Python.h").is_file():
    sys.exit(f"[setup] ERROR: {py_inc}/Python.h missing: install the Python development headers "
             f"(Debian: apt-get install python3-dev, or python{sys.version_info[0]}."
             f"{sys.version_info[1]}-dev)")
builder = r"/opt/python/cp3\d+-cp3\d+t?"
patterns = [
    (re.compile(builder + r"/lib/python3\.\d+t?/site-packages/numpy/_?core/include"), np_inc),
    (re.compile(builder + r"/include/python3\.\d+t?"), py_inc),
]
changed = 0
leftover = []
for path in sorted((venv / "share").glob("*/cmake/*.cmake")):
    text = path.read_text()
    if "/opt/python/" not in text:
        continue
    new = text
    for rx, repl in patterns:
        new = rx.sub(lambda _m, r=repl: r, new)
    if new != text:
        path.write_text(new)
        changed += 1
    if "/opt/python/" in new:
        leftover.append(path)
print(f"[setup]       rewrote {changed} file(s) -> {py_inc} ; {np_inc}")
for path in leftover:
    print(f"[setup]       WARNING: {path} still mentions /opt/python/", file=sys.stderr)
EOF

# ---------------------------------------------------------------------------------------------
log "[5/7] message packages (built only where not importable)"
BUILD_ROOT=""
cleanup() { if [[ -n "$BUILD_ROOT" ]]; then rm -rf "$BUILD_ROOT"; fi; }
trap cleanup EXIT
for pkg in "${MSG_PKGS[@]}"; do
  mapfile -t files < <(msg_files "$pkg")
  pkg_hash="$(hash_files "${files[@]}")"
  pkg_stamp="$STATE/$pkg.sha256"
  if "$PY" -c "$(msg_import "$pkg")" 2>/dev/null; then
    if [[ ! -f "$pkg_stamp" ]]; then
      log "      $pkg: importable (provided elsewhere, e.g. a ROS distro): not building"
      continue
    elif [[ "$(cat "$pkg_stamp")" == "$pkg_hash" ]]; then
      log "      $pkg: already built into $VENV_NAME from current sources"
      continue
    fi
    log "      $pkg: sources changed since the last build: rebuilding"
  fi
  command -v cmake >/dev/null || die "cmake not found (Debian: apt-get install cmake)"
  command -v c++ >/dev/null || die "C++ compiler not found (Debian: apt-get install g++)"
  [[ -n "$BUILD_ROOT" ]] || BUILD_ROOT="$(mktemp -d "${TMPDIR:-/tmp}/audio2pose_msgs.XXXXXX")"
  build_log="$STATE/$pkg.build.log"
  log "      $pkg: cmake configure + build + install into $VENV_NAME (~10 s; log: ${build_log#"$ROOT"/})"
  t0=$SECONDS
  if ! {
    cmake -S "$MSG_SRC/$pkg" -B "$BUILD_ROOT/$pkg" \
      -DCMAKE_PREFIX_PATH="$VENV" -DCMAKE_INSTALL_PREFIX="$VENV" \
      -DPython3_EXECUTABLE="$PY" -DBUILD_TESTING=OFF -DCMAKE_BUILD_TYPE=Release \
      && cmake --build "$BUILD_ROOT/$pkg" -j "$(nproc 2>/dev/null || echo 2)" \
      && cmake --install "$BUILD_ROOT/$pkg"
  } >"$build_log" 2>&1; then
    tail -n 40 "$build_log" >&2
    die "building $pkg failed (full log: $build_log)"
  fi
  "$PY" -c "$(msg_import "$pkg")" || die "$pkg was built but does not import"
  printf '%s\n' "$pkg_hash" >"$pkg_stamp"
  log "      $pkg: done in $((SECONDS - t0)) s"
done

# ---------------------------------------------------------------------------------------------
log "[6/7] Debian tools for the tests (check_urdf)"
DEBIAN_TOOLS=("check_urdf:liburdfdom-tools")
for entry in "${DEBIAN_TOOLS[@]}"; do
  tool="${entry%%:*}" deb="${entry#*:}"
  if command -v "$tool" >/dev/null; then
    log "      $tool: found"
  elif [[ "$(id -u)" == 0 ]] && command -v apt-get >/dev/null; then
    log "      $tool: apt-get install $deb"
    apt-cache show "$deb" >/dev/null 2>&1 || apt-get update -qq >/dev/null 2>&1 || true
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$deb" >/dev/null 2>&1 \
      || log "      WARNING: apt-get install $deb failed; the tests that need $tool will skip"
  else
    log "      $tool: missing; install it with: sudo apt-get install $deb (its tests skip meanwhile)"
  fi
done

# ---------------------------------------------------------------------------------------------
log "[7/7] verifying imports"
"$PY" -c "import rclpy, torch, python_speech_features, pinocchio" || die "import check failed"
for pkg in "${MSG_PKGS[@]}"; do
  "$PY" -c "$(msg_import "$pkg")" || die "import check of $pkg failed"
done
"$PY" -c "import pybullet, yourdfpy, imageio_ffmpeg; imageio_ffmpeg.get_ffmpeg_exe()" \
  || die "import check of the rendering stack (pybullet, yourdfpy, imageio-ffmpeg) failed"
"$PY" -c "import importlib.util, sys; sys.exit(importlib.util.find_spec('audio2pose_ros') is None)" \
  || die "audio2pose_ros is not importable from $VENV_NAME (editable install)"

printf '%s\n' "$INPUT_HASH" >"$STAMP"
log "done in $((SECONDS - START)) s: $VENV_NAME (ROS 2 $DISTRO) is ready"
