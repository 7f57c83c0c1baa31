"""Screenshot of `replay/failures.rrd` in Rerun's web viewer, for the README (docs/ only).

Needs what the project itself does not: Debian's chromium and the `playwright` package
(`pip install playwright`; it drives /usr/bin/chromium, no browser download):

    python docs/screenshot_failures.py \
        results/research_mode/replay/failures.rrd docs/failures_viewer.png 1

The first argument may also be a condition's folder (`results/research_mode/rollouts/fast`):
its blueprint and every episode's file are served, as `rerun <folder>/*` would open them.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from playwright.sync_api import sync_playwright

WEB_PORT, GRPC_PORT = 9090, 9876
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
]


def main(rrd: str, out: str, row: str | None = None, wait: float = 25.0) -> None:
    """Serve `rrd` to the web viewer, optionally pick the `row`-th recording listed, shoot.

    The viewer draws on a canvas, so a recording is picked by scrolling its source list to
    the top and clicking a row (0: the file's summary, 1: the first failed episode, ...).
    """
    home = tempfile.mkdtemp()  # rerun and chromium write settings under HOME
    env = {
        **os.environ,
        "HOME": home,
        "XDG_CONFIG_HOME": f"{home}/.config",
        "XDG_DATA_HOME": f"{home}/.local/share",
        "CI": "1",
    }
    rerun = Path(sys.executable).parent / "rerun"
    server = subprocess.Popen(
        [
            str(rerun),
            "--serve-web",
            "--web-viewer-port",
            str(WEB_PORT),
            "--port",
            str(GRPC_PORT),
            *(sorted(str(f) for f in Path(rrd).glob("[!.]*")) if Path(rrd).is_dir() else [rrd]),
        ],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 120  # many files take a while to load before it serves
        while time.monotonic() < deadline:
            try:
                socket.create_connection(("127.0.0.1", WEB_PORT), timeout=1).close()
                break
            except OSError:
                time.sleep(0.5)
        url = (
            f"http://127.0.0.1:{WEB_PORT}?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{GRPC_PORT}"
            "%2Fproxy&renderer=webgl"
        )
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1600, "height": 1000})
            page.goto(url)
            time.sleep(wait)
            if row is not None:
                page.mouse.move(110, 110)
                page.mouse.wheel(0, -20000)
                time.sleep(2)
                page.mouse.click(130, 146 + 24 * int(row))
                time.sleep(5)
            page.screenshot(path=out)
            browser.close()
    finally:
        server.terminate()


if __name__ == "__main__":
    main(*sys.argv[1:4])
