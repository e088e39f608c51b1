# The two commands of README.md. Both set the workspace up on first use (idempotent).
.PHONY: setup demo test clean

setup:
	@bash scripts/setup.sh

demo: setup
	@bash scripts/demo.sh

test: setup
	@bash scripts/test.sh $(PYTEST_ARGS)

clean:
	rm -rf build install log
