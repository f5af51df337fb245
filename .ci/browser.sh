#!/usr/bin/env bash
# The viewer's browser test needs a real browser: install Debian's Chromium when running as root with apt
# (time-boxed; playwright never downloads a browser of its own here), and the viewer extra + playwright into the
# project's .venv. If anything fails, tests/viewer/test_browser.py skips and says why.
set -uo pipefail
cd "$(dirname "$0")/.."
python3 dev.py setup || exit 1
if [ ! -x /usr/bin/chromium ] && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "browser.sh: installing Debian chromium (time-boxed)"
    export DEBIAN_FRONTEND=noninteractive
    if ! { timeout 300 apt-get update -qq && timeout 900 apt-get install -y -qq chromium >/dev/null; }; then
        echo "browser.sh: chromium install failed or timed out; the browser test will skip"
    fi
fi
[ -x /usr/bin/chromium ] && echo "browser.sh: $(/usr/bin/chromium --version 2>/dev/null || echo chromium present)"
if ! .venv/bin/python -m pip install --disable-pip-version-check -q -c constraints.txt -e ".[viewer]" \
        playwright==1.65.2; then
    echo "browser.sh: could not install the viewer extra / playwright; the viewer tests will skip"
fi
exit 0
