# Thin aliases for dev.py (which needs nothing but Python and pip). DDS stays on this machine.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
PYTHON ?= python3

.PHONY: setup run test bench
setup:
	$(PYTHON) dev.py setup
run:
	$(PYTHON) dev.py run
test:
	$(PYTHON) dev.py test
