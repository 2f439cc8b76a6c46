# audio2pose_ros on a machine without a ROS distro: everything runs from .venv (see README.md).
.PHONY: setup demo test test-long test-fast test-ros test-jazzy lint bench docs default-model style-presets evaluate-style clean

# DDS stays on loopback and each run gets its own domain unless the caller chose one.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export ROS_DOMAIN_ID ?= $(shell shuf -i 1-100 -n 1)

# The ROS 2 wheels the targets run on: Kilted's in .venv (the default), or Jazzy's in .venv-jazzy
# with `make <target> ROS_DISTRO=jazzy` on the command line. A ROS_DISTRO in the environment (a
# sourced ROS distro sets one) does not choose: these venvs never use a distro's own Python.
VENV_DISTRO := $(if $(filter command line,$(origin ROS_DISTRO)),$(ROS_DISTRO),kilted)
VENV := $(if $(filter kilted,$(VENV_DISTRO)),.venv,.venv-$(VENV_DISTRO))
VENV_BIN := $(VENV)/bin

# Create/update the venv (ROS 2 wheels, torch, message packages, editable install). Fast when up
# to date.
setup:
	bash support/setup_venv.sh $(VENV_DISTRO)

# Bundled speech -> live node graph -> recorded MCAP bag + offline CSV, with the default model.
demo: setup
	$(VENV_BIN)/audio2pose demo

# The test suite (unit, DDS integration between processes, CLI, lint): every behaviour, in
# minutes. The soaks and campaigns marked long are left to test-long (pyproject's addopts).
# TEST_WORKERS pytest-xdist processes share the tests: the DDS tests (marked ros) in one of
# them, one at a time as in a serial run, while the others run the rest (test/conftest.py).
# The real-time tests of many processes (marked alone: Chromium, the console, the graph, the
# simulated Pepper, libqi) then run alone: beside CPU-bound workers on 2 cores they were
# starved. Both runs go to the end; the status is the first failure's.
TEST_WORKERS ?= 2
test: setup
	$(VENV_BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadgroup -m "not long and not alone"; \
	status=$$?; \
	$(VENV_BIN)/python -m pytest -p no:xdist -m "alone and not long" --durations=5; \
	alone=$$?; \
	if [ $$status -ne 0 ]; then exit $$status; fi; exit $$alone

# The long tests only: the memory soak, the fault campaign (minutes of audio through the live
# graph) and the floods of node processes; run by hand (CI runs `make test` and `make test-jazzy`).
test-long: setup
	$(VENV_BIN)/python -m pytest -m long

# Everything except the tests marked slow (real-time playback through the node graph) or long.
test-fast: setup
	$(VENV_BIN)/python -m pytest -m "not slow and not long"

# The ROS-facing tests again, on the lane ROS_DISTRO chooses (`make test-ros ROS_DISTRO=jazzy` is
# `make test-jazzy`, which CI runs after `make test`), one at a time: every DDS test but the long
# ones (nodes over DDS between processes, the console's DDS side, the start pose, bag replay), then
# the bag tests without DDS (rosbag2 files of the distro's messages) and the floods of node
# processes (long). Both runs go to the end; the status is the first failure's.
ROS_LANE_FILES := test/test_bag*.py test/test_recording.py test/test_flood_starvation.py test/test_heartbeat_backlog.py
test-ros: setup
	$(VENV_BIN)/python -m pytest -p no:xdist -m "ros and not long"; status=$$?; \
	$(VENV_BIN)/python -m pytest -p no:xdist -m "long or not ros" $(ROS_LANE_FILES) && exit $$status

test-jazzy:
	$(MAKE) test-ros ROS_DISTRO=jazzy

lint: setup
	$(VENV_BIN)/ruff check . && $(VENV_BIN)/ruff format --check . && $(VENV_BIN)/mypy

bench: setup
	$(VENV_BIN)/audio2pose bench

# The documentation (doc/: Sphinx with MyST, as rosdoc2 builds it) into out/docs/, offline; a
# warning fails the build. The Python API pages are generated into doc/generated/ (anew each
# time: stubs of removed modules would stay).
docs: setup
	rm -rf doc/generated
	$(VENV_BIN)/python -m sphinx -W --keep-going -q -b html doc out/docs

TALKING_HEADS ?= ../shared/data/talking_heads
LECTURE_VIDEO ?= ../shared/data/lecture_video/physicsworks.webm
# Rebuild models/default/ from the shared talking-head clips and lecture video: import, train,
# evaluate (head leave-one-source-out, arms on a held-out lecture stretch), model card; then the
# head's temperature chosen over people with every head speaker held out (population.json, the
# card's section): for each speaker the default is trained again without them.
default-model: setup
	nice -n 10 $(VENV_BIN)/audio2pose dataset build-default $(TALKING_HEADS) --lecture $(LECTURE_VIDEO) -o models/default --work-dir out/default-model-work
	nice -n 10 $(VENV_BIN)/python -m audio2pose_ros.style.population --lecture $(LECTURE_VIDEO) $(TALKING_HEADS) out/default-model-work models/default
	nice -n 10 $(VENV_BIN)/python -m audio2pose_ros.style.presets --resolve

# The named style presets (config/styles/*.yaml), measured from the same shared sources with the
# training importers (imported into out/style-sources once).
style-presets: setup
	nice -n 10 $(VENV_BIN)/python -m audio2pose_ros.style.presets $(TALKING_HEADS) $(LECTURE_VIDEO) out/style-sources

# Default vs enrolled (on each source's first 10 s, 20 s and 60 s at most, cross-validated inside
# the enrolment) vs the real floor, on the same held-out speech, into the model card.
# GRID speaker s1 is not bundled: it joins when GRID_S1 holds its imported data set (doc/style.md
# gives the commands that fetch and import it).
GRID_S1 ?= out/style-sources/grid_s1
evaluate-style: style-presets
	nice -n 10 $(VENV_BIN)/audio2pose evaluate-style out/style-sources/talking_heads out/style-sources/lecture $(if $(wildcard $(GRID_S1)/index.json),grid_s1=$(GRID_S1)) --card models/default/MODEL_CARD.md

clean:
	rm -rf .venv .venv-jazzy out doc/generated build install log .pytest_cache .ruff_cache .mypy_cache .hypothesis web/dist web/node_modules
