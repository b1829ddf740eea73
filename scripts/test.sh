#!/usr/bin/env bash
# Installs what the tests need, then runs the whole test suite (real bpy + Mantaflow at tiny sizes).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install.sh
. .venv/bin/activate
python -m pytest -q -ra "$@"
