#!/usr/bin/env bash
# Install the tools that the tests use to check what users see, each in a local folder:
#   - Debian packages (when missing): chromium (headless browser checks of report.html
#     and the viewer), nodejs + npm, python3-venv;
#   - tools/node_modules: the Khronos glTF validator (npm, versions pinned in
#     tools/package-lock.json);
#   - .venv-tools: Mitsuba 3 (pip), which renders the exported scene, and NVIDIA's FLIP
#     evaluator (pip flip-evaluator: .venv-tools/bin/flip) for `svbrdf eval`.
# Idempotent: what is there is kept. Tests that need a tool skip with a reason when it
# is missing, unless SVBRDF_REQUIRE_TOOLS=1 (set by .ci/run), where they fail.
set -euo pipefail
cd "$(dirname "$0")/.."

need=()
command -v chromium >/dev/null 2>&1 || need+=(chromium)
command -v node >/dev/null 2>&1 || need+=(nodejs)
command -v npm >/dev/null 2>&1 || need+=(npm)
python3 -c "import venv, ensurepip" >/dev/null 2>&1 || need+=(python3-venv)
if [ ${#need[@]} -gt 0 ]; then
  echo "test-tools: installing ${need[*]}" >&2
  sudo=""
  if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${need[@]}" >/dev/null
fi

if [ ! -d tools/node_modules/gltf-validator ]; then
  echo "test-tools: npm ci in tools/" >&2
  (cd tools && npm ci --no-audit --no-fund --loglevel=error)
fi

if ! .venv-tools/bin/python -c "import mitsuba" >/dev/null 2>&1; then
  echo "test-tools: pip install mitsuba into .venv-tools" >&2
  python3 -m venv .venv-tools
  .venv-tools/bin/pip install -q --disable-pip-version-check "mitsuba==3.*"
fi
if [ ! -x .venv-tools/bin/flip ]; then
  echo "test-tools: pip install flip-evaluator into .venv-tools" >&2
  [ -d .venv-tools ] || python3 -m venv .venv-tools
  .venv-tools/bin/pip install -q --disable-pip-version-check "flip-evaluator==1.7"
fi
echo "test-tools: chromium, gltf-validator, mitsuba and flip are ready" >&2
