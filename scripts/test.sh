#!/usr/bin/env bash
# Run every test (all packages and test/) with pytest; exit non-zero on any failure.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
# shellcheck disable=SC1091
source .venv/env.sh
exec python -m pytest "$@"
