# The two commands of README.md (demo, test) and the full test run. Each sets the workspace up on first use (idempotent).
.PHONY: setup demo test test-all coverage clean

FAST := not slow and not validation
# pytest-xdist workers for test and test-all: one per CPU this process may use (nproc, as the simulator counts
# them), at most 8; JOBS=N for N, JOBS=0 runs the tests in this one process.
JOBS ?= $(shell n=$$(nproc 2>/dev/null || echo 1); echo $$(( n < 8 ? n : 8 )))

setup:
	@bash scripts/setup.sh

demo: setup
	@bash scripts/demo.sh

test: setup  ## the fast tier: unit tests and quick DDS/CLI integration tests (~6 min on 2 cores)
	@bash scripts/test.sh -n $(JOBS) -m "$(FAST)" $(PYTEST_ARGS)

test-all: setup  ## every test: the fast tier plus the slow and validation tiers
	@bash scripts/test.sh -n $(JOBS) $(PYTEST_ARGS)

coverage: setup  ## both tiers with line coverage per package (log/coverage/)
	@LWS_COVERAGE=fast bash scripts/test.sh -m "$(FAST)" $(PYTEST_ARGS)
	@LWS_COVERAGE=all bash scripts/test.sh $(PYTEST_ARGS)
	@.venv/bin/python scripts/coverage_table.py log/coverage/fast.json log/coverage/all.json

clean:
	rm -rf build install log
