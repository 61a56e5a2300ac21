#!/usr/bin/env bash
# Renders `cmsckf review --html` of a demo flight in headless Chromium and
# takes a full-page screenshot, to look at the report as a reviewer would.
#   scripts/review-screenshot.sh [OUT_DIR]      (default: target/review-screenshot)
# Needs Chromium (Debian: apt-get install chromium); the report itself needs
# nothing at view time (no network, images inline).
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-target/review-screenshot}"
mkdir -p "$out"
browser="$(command -v chromium || command -v chromium-browser || command -v google-chrome || true)"
if [ -z "$browser" ]; then
  echo "no Chromium found: apt-get install chromium" >&2
  exit 1
fi
cargo run --release -- demo --log "$out/demo.mcap" --json > "$out/demo.json"
cargo run --release -- review "$out/demo.mcap" --html "$out/report.html" --json > "$out/review.json"
# --no-sandbox: root in containers; the page is our own file.
"$browser" --headless --no-sandbox --disable-gpu --hide-scrollbars \
  --window-size=1400,5000 --screenshot="$out/report.png" "file://$(realpath "$out/report.html")"
echo "report: $out/report.html  screenshot: $out/report.png"
