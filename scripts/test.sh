#!/usr/bin/env bash
# Run pytest over every package's tests and test/ with the given arguments (make test: the fast tier's
# -m expression; make test-all: none); exit non-zero on any failure. LWS_COVERAGE=NAME adds line
# coverage of the three packages, nodes and CLI subprocesses included, written to log/coverage/NAME.json.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
# shellcheck disable=SC1091
source .venv/env.sh
cov=()
if [[ -n "${LWS_COVERAGE:-}" ]]; then
  mkdir -p log/coverage
  rm -f .coverage .coverage.*
  cov=(--cov --cov-config=.coveragerc --cov-report="json:log/coverage/${LWS_COVERAGE}.json" --cov-report=)
fi
exec python -m pytest "${cov[@]}" "$@"
