#!/usr/bin/env bash
# Set up glacimap on a fresh machine: system packages (when missing), a virtualenv, the
# project with its test and benchmark extras. Idempotent; safe to re-run.
#   usage: scripts/setup.sh [VENV_DIR]
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
venv=${1:-$here/.venv}
python=${PYTHON:-python3}

# 1. System packages listed in scripts/apt-packages.txt (one per line, # comments).
mapfile -t wanted < <(grep -v '^\s*#' "$here/scripts/apt-packages.txt" | awk 'NF {print $1}')
missing=()
for pkg in "${wanted[@]}"; do
  dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing system packages: ${missing[*]}"
  sudo_cmd=""; [ "$(id -u)" -ne 0 ] && sudo_cmd="sudo"
  $sudo_cmd apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# 2. Python >= 3.11 in a virtualenv.
"$python" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' || {
  echo "setup: glacimap needs Python >= 3.11; set PYTHON=python3.11" >&2; exit 1; }
[ -x "$venv/bin/python" ] || "$python" -m venv "$venv"
"$venv/bin/python" -m pip install -q --upgrade pip 2>&1 | grep -v "Location 'file" || true
"$venv/bin/python" -m pip install -q -e "$here[test,bench]" 2>&1 | grep -v "Location 'file" || true
"$venv/bin/python" -c "import terrain, toolkit" || { echo "setup: install failed" >&2; exit 1; }
echo "setup: ready ($venv)"
