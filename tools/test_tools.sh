#!/usr/bin/env bash
# The tools that some tests need beyond the Python environment, installed where this machine allows (`make test`
# and `make test-tools` run this script; CI runs `make test`):
#
#   tools/test_tools.sh               install what can be installed; one line per tool still missing
#   tools/test_tools.sh CMD ARGS...   the same, then run CMD (make test: pytest) with DUALTALKER_REQUIRE_*=1 set
#                                     for every tool present, so that its tests fail instead of skipping
#
#   tool                            tests                                    installed by
#   glTF validator + three.js       tests/test_export.py (validator, three)  npm ci --prefix tools/node (pinned, ~4 s)
#   KaTeX                           tests/test_notebook_math.py              npm ci --prefix tools/katex (~1 MB, ~1 s)
#   chromium                        tests/test_export.py (the html plays)    apt-get install chromium (~22 s)
#   real recordings                 tests/test_recogniser.py (a real voice)  apt-get install asterisk-core-sounds-en-wav
#                                   (CC-BY-SA, one professional voice, 25 MB; nothing is redistributed)
#
# The npm installs go into the checkout (gitignored) and are redone only when a package-lock.json changes; the
# Debian packages are installed only by root on a machine with apt-get (containers, CI), once. Elsewhere the script
# prints the command that installs each missing tool, and its tests are skipped with that reason (pytest lists every
# skipped test at the end, `-ra` in pyproject.toml). With CI=true a failed npm or chromium install stops here (status
# 1), so CI never passes with those tests skipped; the recordings may be missing there too (then skipped, said so).
set -uo pipefail
cd "$(dirname "$0")/.."

is_root_with_apt() { [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; }
missing() { echo "test tools: missing $1 ($2 skipped): $3"; }
ci_stop() {  # an install that was tried and failed stops CI; elsewhere the "missing" line below says what to do
  if [ "${CI:-}" = true ]; then echo "test tools: $1 failed (CI=true: stopping)" >&2; exit 1; fi
}
apt_updated=
apt_install() {  # apt_install PACKAGE: quietly, with its recommended packages, after one apt-get update
  { [ -n "$apt_updated" ] || apt-get update -qq; } && apt_updated=1 &&
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$1" >/dev/null
}
npm_ci() {  # npm_ci FOLDER: npm ci unless its node_modules already match its package-lock.json
  local marker="$1/node_modules/.package-lock.json"
  [ -f "$marker" ] && [ ! "$1/package-lock.json" -nt "$marker" ] && return 0
  npm ci --prefix "$1" --no-audit --no-fund --loglevel=error
}

node_hint=
if command -v npm >/dev/null && command -v node >/dev/null; then
  npm_ci tools/node || ci_stop "npm ci --prefix tools/node"
  npm_ci tools/katex || ci_stop "npm ci --prefix tools/katex"
else
  node_hint=" (needs node and npm: sudo apt-get install nodejs npm on Debian)"
fi
[ -d tools/node/node_modules/gltf-validator ] && [ -d tools/node/node_modules/three ] ||
  missing "the glTF validator and three.js" "the validator and three.js export tests" \
    "npm ci --prefix tools/node$node_hint"
[ -d tools/katex/node_modules/katex ] ||
  missing KaTeX "the notebook-math test" "make katex$node_hint"

chromium=${DTL_CHROMIUM:-$(command -v chromium || command -v chromium-browser || true)}
if [ -z "$chromium" ] && is_root_with_apt; then
  if apt_install chromium; then chromium=$(command -v chromium); else ci_stop "apt-get install chromium"; fi
fi
[ -n "$chromium" ] || missing chromium "the test that plays the html export" \
  "sudo apt-get install chromium (Debian), or set DTL_CHROMIUM to a chromium executable"

voices=/usr/share/asterisk/sounds/en_US_f_Allison
if [ ! -d "$voices" ] && is_root_with_apt; then
  apt_install asterisk-core-sounds-en-wav || true  # not in every distribution: a skip, even in CI
fi
[ -d "$voices" ] || missing "the real recordings" "the real-voice recogniser test" \
  "sudo apt-get install asterisk-core-sounds-en-wav (Debian)"

# Present -> required (unless already set): a test that then cannot use its tool fails, saying why.
if [ -d tools/node/node_modules/gltf-validator ] && [ -n "$chromium" ]; then
  export DUALTALKER_REQUIRE_EXPORT_TOOLS=${DUALTALKER_REQUIRE_EXPORT_TOOLS:-1}
fi
if [ -d tools/katex/node_modules/katex ] && command -v node >/dev/null; then
  export DUALTALKER_REQUIRE_KATEX=${DUALTALKER_REQUIRE_KATEX:-1}
fi
if [ -d "$voices" ]; then
  export DUALTALKER_REQUIRE_REAL_VOICES=${DUALTALKER_REQUIRE_REAL_VOICES:-1}
fi
required=$(env | grep -o '^DUALTALKER_REQUIRE_[A-Z_]*=1' | sort | tr '\n' ' ')
required=${required% }
echo "test tools: required (fail instead of skipping): ${required:-none}"

[ $# -eq 0 ] || exec "$@"  # the command's exit status is the script's (pytest's 5, "no tests", included)
