#!/usr/bin/env bash
# Make sure a headless-capable Chromium exists for the viewer's browser test
# (tests/test_viewer.py). Installs Debian's chromium when possible; where it cannot,
# says so and exits 0: the browser test then skips with the reason.
set -uo pipefail
for b in chromium chromium-browser google-chrome; do
    if command -v "$b" >/dev/null 2>&1; then echo "found browser: $(command -v "$b")"; exit 0; fi
done
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then SUDO="sudo -n"; else
        echo "WARNING: no Chromium, and no root to run 'apt-get install chromium': the viewer's browser test will be skipped" >&2
        exit 0
    fi
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "WARNING: no Chromium and no apt-get: install Chromium (or set MI_PLUGINS_BROWSER to a Chrome/Chromium binary); the viewer's browser test will be skipped" >&2
    exit 0
fi
echo "No Chromium found; installing Debian's chromium (for the viewer's browser test) ..."
$SUDO apt-get update -qq || true
if ! $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium >/dev/null; then
    echo "WARNING: 'apt-get install chromium' failed: the viewer's browser test will be skipped" >&2
    exit 0
fi
echo "installed chromium"
