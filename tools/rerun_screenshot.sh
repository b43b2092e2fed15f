#!/usr/bin/env bash
# A screenshot of Rerun's web viewer showing a recording, taken in headless Chromium
# (software WebGL) driven by playwright-core: how docs/images/rerun_*.png were made.
#
#   tools/rerun_screenshot.sh RUN.rrd OUT.png [SECONDS]
#
# Needs `rerun` from rerun-sdk 0.36.3 (data/venv after tools/test.sh, or PATH),
# Debian's chromium, and node/npm (playwright-core is installed into a temporary
# folder; no browser is downloaded). The viewer shows the recording's last frame in its
# default layout after SECONDS (default 60; software rendering is slow): the 3D view
# (trajectories, camera, map, dense mesh), the image with keypoints and boxes, events.
set -euo pipefail
rrd=$1
out=$(realpath -m "$2")
wait_s=${3:-60}
here=$(cd "$(dirname "$0")/.." && pwd)
rerun=$(command -v rerun || echo "$here/data/venv/bin/rerun")
[ -x "$rerun" ] || { echo "error: no rerun viewer (pip install rerun-sdk==0.36.3)" >&2; exit 1; }
command -v chromium >/dev/null || { echo "error: no chromium (apt-get install chromium)" >&2; exit 1; }
command -v npm >/dev/null || { echo "error: no npm (apt-get install npm)" >&2; exit 1; }
work=$(mktemp -d)
# The viewer in a session of its own, so that it ends with the script (its server
# runs in a child process).
XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp} setsid "$rerun" --web-viewer --web-viewer-port 9090 "$rrd" \
    >"$work/viewer.log" 2>&1 &
viewer=$!
trap 'kill -- -$viewer 2>/dev/null || true; rm -rf "$work"' EXIT
npm install --silent --prefix "$work" playwright-core@1 >/dev/null
for _ in $(seq 1 30); do
    curl -sf http://127.0.0.1:9090 >/dev/null && break
    sleep 1
done
cat >"$work/shot.js" <<'EOF'
const { chromium } = require('playwright-core');
(async () => {
  const [url, out, seconds] = process.argv.slice(2);
  const browser = await chromium.launch({
    executablePath: '/usr/bin/chromium',
    args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
      '--ignore-gpu-blocklist', '--disable-background-networking',
      '--disable-component-update', '--disable-sync', '--no-first-run'],
  });
  const page = await browser.newPage({ viewport: { width: 1600, height: 1000 } });
  await page.goto(url);
  await page.waitForTimeout(1000 * Number(seconds));
  await page.screenshot({ path: out, timeout: 300000 });
  await browser.close();
})();
EOF
NODE_PATH="$work/node_modules" node "$work/shot.js" \
    "http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876%2Fproxy" "$out" "$wait_s"
echo "wrote $out"
