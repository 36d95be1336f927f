#!/usr/bin/env bash
# Install everything the tests need, then run them. This is the README's test command and what
# .ci/run calls. Needs root for apt-get (gpsd for the end-to-end tests; proj-data for the
# full-resolution EGM96 grid the geoid test compares against; chromium to render the gap
# tool's HTML report).
set -euo pipefail
cd "$(dirname "$0")/.."
if command -v apt-get >/dev/null 2>&1; then
  need=()
  for pkg in gpsd gpsd-clients proj-data chromium; do
    dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
  done
  if [ ${#need[@]} -gt 0 ]; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
  fi
fi
python3 -m pip install -q -e '.[test]'
python3 -m ruff check virtualgps tests tools
# (the ten slowest tests listed at the end: CI must finish in 30 minutes, docs/development.md)
python3 -m pytest -q --durations=10 "$@"
