"""Shared check of the interactive HTML reports: open a page offline in headless Chromium (WebGL through
SwiftShader) and return what it rendered. Chromium is required under CI (``.ci/run`` installs it); elsewhere a
test that needs it is skipped."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--hide-scrollbars"]


def chromium() -> str:
    """The Chromium executable (fails under CI, skips elsewhere when there is none)."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    if os.environ.get("CI"):
        pytest.fail("Chromium is required under CI (apt-get install chromium) but was not found")
    pytest.skip("no Chromium on this machine (install Debian's `chromium` to run this check); not under CI")


def render_page(page: Path, work: Path, window=(1200, 1400)) -> tuple[str, np.ndarray]:
    """(the rendered DOM without its scripts, the screenshot as an (h, w, 3) float array in [0, 1]) of ``page``.

    The DOM has its ``<script>`` elements removed: the embedded plotly.js source contains the message
    'WebGL is not supported' itself, so only the rendered page can tell whether it was shown."""
    exe = chromium()
    url = Path(page).as_uri()
    common = FLAGS + [f"--user-data-dir={work / 'profile'}", "--virtual-time-budget=15000"]
    dom = subprocess.run([exe, *common, "--dump-dom", url], capture_output=True, text=True, timeout=180)
    assert dom.returncode == 0, dom.stderr[-2000:]
    rendered = re.sub(r"<script\b.*?</script>", "", dom.stdout, flags=re.S | re.I)
    shot = work / "shot.png"
    run = subprocess.run([exe, *common, f"--window-size={window[0]},{window[1]}", f"--screenshot={shot}", url],
                         capture_output=True, text=True, timeout=180)
    assert run.returncode == 0 and shot.exists(), run.stderr[-2000:]
    import matplotlib.image as mpimg

    return rendered, mpimg.imread(shot)[..., :3]
