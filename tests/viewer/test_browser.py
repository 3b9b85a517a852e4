"""The page in a real browser: Playwright for Python driving Debian's
``chromium`` (installed by ``scripts/ensure-chromium.sh``; no browser downloads). The image the
page shows (a JPEG) is read back from its <img> and compared with ``GET /api/frame.png``."""

from __future__ import annotations

import base64
import os
import shutil

import httpx
import mitsuba as mi
import numpy as np
import pytest
from viewer_oracle import pixels

CHROMIUM = os.environ.get("PHOTONMAP_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
sync_api = pytest.importorskip("playwright.sync_api", reason="pip install playwright (dev extra)")
if not os.path.exists(CHROMIUM):
    pytest.skip(
        f"no chromium at {CHROMIUM}: run `bash scripts/ensure-chromium.sh` as root "
        "(apt-get install chromium) or set PHOTONMAP_CHROMIUM",
        allow_module_level=True,
    )


@pytest.fixture(scope="module")
def browser():
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=["--headless=new"])
        yield b
        b.close()


def _get(url: str, **kwargs):
    """GET with the token of the viewer under test (its API refuses requests without it)."""
    return httpx.get(url, headers=HEADERS, **kwargs)


HEADERS: dict = {}


@pytest.fixture
def page(browser, server):
    base, viewer = server
    HEADERS["X-Photonmap-Token"] = viewer.token
    page = browser.new_page(viewport={"width": 900, "height": 600})
    page.problems = []
    page.on("console", lambda m: m.type == "error" and page.problems.append(m.text))
    page.on("pageerror", lambda e: page.problems.append(str(e)))
    page.goto(f"{base}/?token={viewer.token}")  # the URL photonmap view prints
    page.wait_for_function("window.viewer && viewer.frames > 0 && viewer.state !== null")
    yield page
    page.close()


def settled(page, base) -> np.ndarray:
    """Wait until the page shows the full-size frame of every change made so far; return the
    pixels it shows, after checking they are the server's current frame."""
    page.wait_for_function("!viewer.busy()")
    version = _get(base + "/api/frame.json", timeout=60).json()["version"]
    page.wait_for_function(
        f"viewer.meta && !viewer.meta.preview && viewer.meta.version >= {version}", timeout=30000
    )
    shown = page.evaluate(
        """async () => {
            const buf = await (await fetch(viewer.imageUrl)).arrayBuffer();
            let s = ""; new Uint8Array(buf).forEach((b) => (s += String.fromCharCode(b)));
            return btoa(s);
        }"""
    )
    image = pixels(base64.b64decode(shown))
    latest = _get(base + "/api/frame.png", timeout=60)
    if int(latest.headers["X-Frame-Version"]) == page.evaluate("viewer.meta.version"):
        # the streamed JPEG (quality 92) is the frame within JPEG's error (measured 0.77 / 255)
        assert np.abs(image.astype(int) - pixels(latest.content)).mean() < 1.5
    return image


def state(base) -> dict:
    return _get(base + "/api/state").json()


def test_page_loads_without_console_errors(page, server):
    base, _ = server
    settled(page, base)
    assert page.inner_text("#title") == "glass_sphere_fog · volume"
    assert "reran" in page.inner_text("#stats")
    assert page.locator("#timings tr").count() == len(state(base)["stages"])
    assert page.is_hidden("#error")
    assert page.problems == []


def test_dragging_the_light_changes_the_image(page, server):
    """The light starts above the picture: "place light" mode puts it under the mouse (at its
    depth from the camera), then the drag moves it; its ring follows the mouse."""
    base, viewer = server
    before, light0 = settled(page, base), state(base)["lights"][0]["position"]
    box = page.locator("#overlay").bounding_box()
    page.check("input[name=mode][value=light]")
    x, y = 0.5 * box["width"], 0.2 * box["height"]
    page.mouse.move(box["x"] + x, box["y"] + y)
    page.mouse.down()
    for step in range(1, 6):
        page.mouse.move(box["x"] + x - 6 * step, box["y"] + y - 2 * step)
    page.mouse.up()
    page.check("input[name=mode][value=camera]")
    after = settled(page, base)
    light1 = state(base)["lights"][0]["position"]
    assert np.linalg.norm(np.subtract(light1, light0)) > 0.1
    assert np.abs(after.astype(int) - before).mean() > 0.5
    x1, y1 = page.evaluate("viewer.lightScreen(0)")
    assert abs(x1 - (x - 30)) < 1 and abs(y1 - (y - 10)) < 1
    # the ring is where Mitsuba's camera sees the light (sample_direction's film position)
    it = mi.Interaction3f()
    it.p = mi.Point3f(*light1)
    uv = np.array(viewer.adapter.sensor.sample_direction(it, mi.Point2f(0.5))[0].uv).ravel()
    film = np.array(viewer.adapter.sensor.film().size())
    np.testing.assert_allclose([x1, y1], uv / film * [box["width"], box["height"]], atol=0.5)
    # and the ring can be grabbed and dragged in camera mode
    page.mouse.move(box["x"] + x1, box["y"] + y1)
    page.mouse.down()
    page.mouse.move(box["x"] + x1 + 20, box["y"] + y1, steps=4)
    page.mouse.up()
    settled(page, base)
    x2, y2 = page.evaluate("viewer.lightScreen(0)")
    assert abs(x2 - (x1 + 20)) < 1 and abs(y2 - y1) < 1
    assert page.problems == []


def test_orbiting_moves_the_camera(page, server):
    base, _ = server
    before, origin0 = settled(page, base), state(base)["camera"]["origin"]
    box = page.locator("#overlay").bounding_box()
    page.mouse.move(box["x"] + 10, box["y"] + box["height"] - 10)
    page.mouse.down()
    page.mouse.move(box["x"] + 60, box["y"] + box["height"] - 10, steps=5)
    page.mouse.up()
    after = settled(page, base)
    assert state(base)["camera"]["origin"] != origin0
    assert np.abs(after.astype(int) - before).mean() > 0.5


def test_a_slider_changes_the_image(page, server):
    base, _ = server
    before = settled(page, base)
    page.select_option("#material-name", "glass")
    page.locator("#mat-ior-range").fill("1.2")
    after = settled(page, base)
    assert state(base)["materials"]["glass"]["ior"] == pytest.approx(1.2)
    assert np.abs(after.astype(int) - before).mean() > 0.5
    assert page.problems == []


def test_an_invalid_value_shows_an_error(page, server):
    base, _ = server
    settled(page, base)
    before = state(base)
    page.select_option("#material-name", "glass")
    page.locator("#mat-ior").fill("0.5")
    page.locator("#mat-ior").press("Enter")
    page.wait_for_selector("#error:not([hidden])")
    assert "must be >= 1" in page.inner_text("#error")
    assert state(base) == before
    page.wait_for_function("document.getElementById('mat-ior').value !== '0.5'")
    assert float(page.input_value("#mat-ior")) == pytest.approx(before["materials"]["glass"]["ior"])


def test_two_quick_changes_leave_the_image_of_the_second(page, server):
    base, _ = server
    settled(page, base)
    box = page.locator("#light-intensity")
    box.fill("5")
    box.press("Enter")
    first = settled(page, base)
    box.fill("80")
    box.press("Enter")
    second = settled(page, base)
    assert np.abs(second.astype(int) - first).mean() > 1
    page.evaluate(  # two changes in one task: the second comes while the first is in flight
        """() => {
            const box = document.getElementById("light-intensity");
            box.value = "5"; box.dispatchEvent(new Event("change"));
            box.value = "80"; box.dispatchEvent(new Event("change"));
        }"""
    )
    shown = settled(page, base)
    assert state(base)["lights"][0]["intensity"] == 80
    np.testing.assert_array_equal(shown, second)
    assert page.problems == []
