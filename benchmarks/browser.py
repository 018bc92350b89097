"""A pghm web page in headless Chromium with software WebGL (SwiftShader), driven by
``page_driver.js``: the shots it drew (as PNGs), its first frame's time and a loop's frame times.

Chromium's ``--dump-dom`` prints the page's DOM once its load event has run; the player and the
driver draw synchronously before it, so the printed DOM holds the driver's results. No network,
no browser automation library: one Chromium process per call.
"""

from __future__ import annotations

import base64
import html
import io
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np

DRIVER = Path(__file__).with_name("page_driver.js")
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",  # as root (CI containers) Chromium refuses to start sandboxed
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--no-first-run",
    "--disable-extensions",
    "--dump-dom",
]
RESULT = re.compile(r'<pre id="pghm-result">(.*?)</pre>', re.S)
MESSAGE = re.compile(r'<div id="message"[^>]*>([^<]+)</div>')


def chromium() -> str | None:
    """The Chromium executable, or None when it is not installed."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


def drive(page: Path, plan: dict, timeout: float = 300.0) -> dict:
    """Open ``page`` (a file pghm export --web wrote) with ``plan`` ({"width", "height", "shots":
    [{"frame", "yaw", "pitch", "zoom"}], "loop": bool, "background": [r, g, b]}); the driver's
    results with each shot's ``image`` an (H, W, 3) uint8 array."""
    from PIL import Image

    executable = chromium()
    if executable is None:
        raise FileNotFoundError("chromium is not installed (scripts/setup.sh installs it)")
    text = page.read_text(encoding="utf-8")
    end = text.rindex("</body>")
    plan_json = json.dumps(plan).replace("</", "<\\/")
    extra = (
        f'<script type="application/json" id="pghm-plan">{plan_json}</script>\n'
        f"<script>\n{DRIVER.read_text(encoding='utf-8')}\n</script>\n"
    )
    driven = page.with_name(page.stem + ".driven.html")
    driven.write_text(text[:end] + extra + text[end:], encoding="utf-8")
    try:
        window = f"--window-size={plan['width']},{plan['height']}"
        done = subprocess.run(
            [executable, *CHROMIUM_FLAGS, window, driven.as_uri()], capture_output=True, text=True, timeout=timeout
        )
    finally:
        driven.unlink(missing_ok=True)
    found = RESULT.findall(done.stdout)  # the last: the element the driver appended at the end
    if not found:
        shown = MESSAGE.search(done.stdout)  # what the player showed, if it stopped
        said = html.unescape(shown.group(1)) if shown else done.stderr[-2000:]
        raise RuntimeError(f"the page wrote no result (chromium exit {done.returncode}): {said}")
    result = json.loads(html.unescape(found[-1]))
    for shot in result["shots"]:
        png = base64.b64decode(shot.pop("png").split(",", 1)[1])
        shot["image"] = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
    return result
