"""Record the README's viewer figures (issue 14 item 5): a screenshot of ``photonmap view
glass_sphere_fog`` and a short sequence of the light being dragged across the scene with the
mouse (the light first set just above the fog box, where its ring is in the picture, then the
ring dragged from left to right), assembled into an animated WebP.

Drives Debian's chromium with Playwright (as the browser tests do) against the viewer at the
scene's default settings, waits for each full-size frame, and writes ``docs/viewer.png`` and
``docs/viewer_drag.webp``::

    PYTHONPATH=src .venv/bin/python scripts/viewer_demo.py [--steps 12] [--set grid=64 ...]
"""

from __future__ import annotations

import argparse
import io
from pathlib import Path

import httpx
from PIL import Image
from playwright.sync_api import sync_playwright

from photonmap.viewer import Background, Viewer

DOCS = Path(__file__).resolve().parent.parent / "docs"
LIGHT = {"position": [0.5, 1.25, 0.5], "intensity": 3.0}  # 0.69 from the ball's centre, not 2.56


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="glass_sphere_fog")
    parser.add_argument("--steps", type=int, default=12, help="frames of the drag")
    parser.add_argument("--set", dest="sets", action="append", default=[], help="KEY=VALUE (int)")
    parser.add_argument("--chromium", default="/usr/bin/chromium")
    args = parser.parse_args(argv)
    overrides = {k: int(v) for k, v in (s.split("=", 1) for s in args.sets)}
    background = Background(Viewer(args.scene, "volume", overrides))
    base = background.url.rstrip("/")

    def settle(page):
        page.wait_for_function("!viewer.busy()")
        version = httpx.get(base + "/api/frame.json", timeout=600).json()["version"]
        page.wait_for_function(f"viewer.meta && !viewer.meta.preview && "
                               f"viewer.meta.version >= {version}", timeout=600_000)  # fmt: skip
        page.wait_for_timeout(100)

    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=args.chromium, args=["--headless=new"])
            page = browser.new_page(viewport={"width": 1000, "height": 780})
            page.goto(base + "/")
            page.wait_for_function("window.viewer && viewer.frames > 0")
            settle(page)
            # the scene's light is far above the picture: bring it just over the fog box, in
            # view (intensity scaled by the squared distance to the ball), then drag its ring
            httpx.post(base + "/api/update", json={"lights": [LIGHT]}).raise_for_status()
            settle(page)
            page.wait_for_function("viewer.state.lights[0].intensity === 3")  # the page reloads
            box = page.locator("#overlay").bounding_box()
            x, y = page.evaluate("viewer.lightScreen(0)")
            offsets = [-1 + 2 * i / (args.steps - 1) for i in range(args.steps)]
            frames = []
            page.mouse.move(box["x"] + x, box["y"] + y)
            page.mouse.down()  # grab the ring, then sweep it from left to right
            for i, t in enumerate(offsets):
                page.mouse.move(box["x"] + x + t * 0.25 * box["width"], box["y"] + y, steps=3)
                settle(page)
                frames.append(Image.open(io.BytesIO(page.screenshot())).convert("RGB"))
                if i == args.steps // 3:
                    page.screenshot(path=str(DOCS / "viewer.png"))
            page.mouse.up()
            browser.close()
    finally:
        background.stop()
    frames[0].save(DOCS / "viewer_drag.webp", save_all=True, append_images=frames[1:],
                   duration=400, loop=0, quality=70)  # fmt: skip
    print(f"wrote {DOCS / 'viewer.png'} and {DOCS / 'viewer_drag.webp'} ({len(frames)} frames)")


if __name__ == "__main__":
    main()
