#!/usr/bin/env bash
# Regenerate docs/img/hand_animation.png: the `awiwi-drake animate` recording rendered by headless
# Chromium (apt-get install -y chromium) at the start (open hand) and during the grasp.
# The grasp frame is taken by Chromium's virtual time (~0.8 s into the 1.5 s motion); check the image.
set -euo pipefail
cd "$(dirname "$0")/.."
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
python3 -m awiwi_drake animate --out "$tmp/hand.html" --duration 1.5
shot() {  # budget_ms out.png
  chromium --headless --no-sandbox --disable-gpu --disable-background-networking --disable-component-update \
    --disable-sync --window-size=480,420 --virtual-time-budget="$1" --screenshot="$2" "file://$tmp/hand.html" \
    >/dev/null 2>&1
}
shot 50 "$tmp/open.png"
shot 800 "$tmp/grasp.png"
python3 - "$tmp" <<'PY'
import sys
from PIL import Image
d = sys.argv[1]
a, b = Image.open(f"{d}/open.png"), Image.open(f"{d}/grasp.png")
out = Image.new("RGB", (a.width + b.width, a.height))
out.paste(a, (0, 0))
out.paste(b, (a.width, 0))
out.save("docs/img/hand_animation.png")
print("wrote docs/img/hand_animation.png")
PY
