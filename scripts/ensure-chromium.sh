#!/usr/bin/env bash
# Make sure Debian's chromium is installed for the viewer's browser tests (tests/viewer/test_browser.py
# drives it with Playwright for Python; Playwright's own browser downloads are never used).
# Not fatal: without chromium (not root, no apt-get, offline) those tests skip and say why.
set -uo pipefail
for exe in "${PHOTONMAP_CHROMIUM:-}" /usr/bin/chromium /usr/bin/chromium-browser; do
  if [ -n "$exe" ] && [ -x "$exe" ]; then echo "ensure-chromium: $exe found"; exit 0; fi
done
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  echo "ensure-chromium: installing chromium with apt-get"
  if apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; then
    exit 0
  fi
fi
echo "ensure-chromium: chromium not installed; the browser tests will skip. Install it with" >&2
echo "  'sudo apt-get install chromium' (Debian/Ubuntu), or set PHOTONMAP_CHROMIUM to a Chromium binary." >&2
exit 0
