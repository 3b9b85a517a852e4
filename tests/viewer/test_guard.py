"""A viewer only its own page can drive: a token per server, ``Host`` and
``Origin`` of the server only, JSON bodies of at most 1 MB, errors that never echo the request or
carry a traceback; and an update whose render fails is rolled back (state and frame as before,
the reason once), while one beyond memory is refused before it is applied."""

from __future__ import annotations

import json

import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect
from viewer_oracle import SIZE, pixels

from photonmap.viewer import Background, Viewer, create_app
from photonmap.viewer.guard import MAX_BODY

EVIL = "http://evil.example"


@pytest.fixture
def bare(viewer):
    """A client with no token."""
    with TestClient(create_app(viewer), base_url="http://127.0.0.1") as c:
        yield c


def test_cross_site_update_is_refused(client, viewer):
    before = client.get("/api/state").json()
    body = json.dumps({"lights": [{"intensity": 99}]})
    for headers in (
        {"Origin": EVIL, "Content-Type": "text/plain"},  # a "simple" cross-site request
        {"Origin": EVIL, "Content-Type": "application/json"},
        {"Content-Type": "text/plain"},  # a form-like body, even with the token
    ):
        reply = client.post("/api/update", content=body, headers=headers)
        assert reply.status_code in (403, 415), (headers, reply.text)
        assert "99" not in reply.text
    assert client.get("/api/state").json() == before


def test_token_is_required(bare, viewer):
    for method, path in (("GET", "/api/state"), ("GET", "/api/frame.png"), ("GET", "/"),
                         ("POST", "/api/update"), ("POST", "/api/reset")):  # fmt: skip
        reply = bare.request(method, path, json={} if method == "POST" else None)
        assert reply.status_code == 403 and "token" in reply.json()["detail"], (method, path)
    assert bare.get("/api/state", headers={"X-Photonmap-Token": "wrong"}).status_code == 403
    assert bare.get("/api/state", headers={"Authorization": f"token {viewer.token}"}).is_success
    assert bare.get("/static/viewer.js").status_code == 200  # the page's own files
    page = bare.get(f"/?token={viewer.token}")  # the URL photonmap view prints
    assert page.status_code == 200 and "samesite=strict" in page.headers["set-cookie"].lower()
    assert bare.get("/api/state").status_code == 200  # the page's cookie from now on


def test_host_must_be_the_servers_own(client):
    for host in ("evil.example", "evil.example:8000", "127.0.0.1.evil.example"):
        reply = client.get("/api/state", headers={"Host": host})
        assert reply.status_code == 421, host
    assert client.get("/api/state", headers={"Host": "localhost:8000"}).status_code == 200


def test_websocket_from_another_site_or_without_token_is_refused(bare, viewer):
    url = f"ws://127.0.0.1/api/stream?token={viewer.token}"
    for target, headers in ((url, {"Origin": EVIL}), (url.split("?")[0], {}),
                            (url.replace("127.0.0.1", "evil.example"), {})):  # fmt: skip
        with pytest.raises(WebSocketDisconnect):
            with bare.websocket_connect(target, headers=headers) as ws:
                ws.receive_json()
    with bare.websocket_connect(url, headers={"Origin": "http://127.0.0.1"}) as ws:
        assert ws.receive_json()["type"] == "frame"


def test_bodies_are_capped_and_never_echoed(client):
    before = client.get("/api/state").json()
    big = b'{"params": {"photons": [' + b"1," * (5 << 20) + b"1]}}"  # 10 MB
    reply = client.post("/api/update", content=big, headers={"Content-Type": "application/json"})
    assert reply.status_code == 413 and len(reply.content) < 200
    array = [7.25] * 100_000  # under the cap: refused by the checks, not repeated
    reply = client.post("/api/update", json={"camera": {"origin": array}})
    assert reply.status_code == 422 and len(reply.content) < 400 and "7.25" not in reply.text
    nested = b"[" * 100_000 + b"]" * 100_000
    reply = client.post("/api/update", content=nested,
                        headers={"Content-Type": "application/json"})  # fmt: skip
    assert reply.status_code == 422 and "nested" in reply.json()["detail"]
    assert client.get("/api/state").json() == before
    assert MAX_BODY == 1 << 20


def test_an_internal_error_is_a_short_500(client, viewer, monkeypatch, capsys):
    def broken():
        raise RuntimeError("boom\nwith a second line")

    monkeypatch.setattr(viewer, "state", broken)
    reply = client.get("/api/state")
    assert reply.status_code == 500 and "Traceback" not in reply.text and "boom" not in reply.text
    log = capsys.readouterr()
    assert "Traceback" not in log.out + log.err
    assert "failed: RuntimeError: boom" in log.out


def test_real_server_checks_host_and_origin():
    """uvicorn in front: the same checks, the page URL with its token."""
    from viewer_oracle import OVERRIDES, SCENE

    with Background(Viewer(SCENE, "volume", dict(OVERRIDES), SIZE)) as bg:
        assert bg.page_url.startswith(bg.url + "?token=")
        assert httpx.get(bg.page_url, timeout=60).status_code == 200
        assert httpx.get(bg.url + "api/state", headers=bg.headers).status_code == 200
        assert httpx.get(bg.url + "api/state").status_code == 403
        evil = {**bg.headers, "Host": "evil.example"}
        assert httpx.get(bg.url + "api/state", headers=evil).status_code == 421
        reply = httpx.post(bg.url + "api/update", content=b'{"lights": [{"intensity": 3}]}',
                           headers={**bg.headers, "Origin": EVIL,
                                    "Content-Type": "text/plain"})  # fmt: skip
        assert reply.status_code == 403


@pytest.fixture
def surface_viewer():
    """The issue's case: the surface method on a file scene."""
    v = Viewer("examples/cornell_box.xml", "surface",
               {"photons": 2000, "caustic_photons": 0, "fg_rays": 2, "emitter_spp": 0}, (32, 24))
    yield v
    v.close()


def test_an_update_beyond_memory_is_refused_before_it_is_applied(surface_viewer):
    v = surface_viewer
    with TestClient(create_app(v), base_url="http://127.0.0.1",
                    headers={"X-Photonmap-Token": v.token}) as client:  # fmt: skip
        before = client.get("/api/state").json()
        first = client.get("/api/frame.png")
        reply = client.post("/api/update", json={"params": {"photons": 10**12}})
        assert reply.status_code == 422
        assert reply.json()["detail"].startswith("these surface settings need about")
        assert client.get("/api/state").json() == before
        again = client.get("/api/frame.png")
        assert again.status_code == 200 and "X-Frame-Error" not in again.headers
        np.testing.assert_array_equal(pixels(again.content), pixels(first.content))


def test_a_failed_render_is_rolled_back_and_reported_once(surface_viewer, monkeypatch):
    """A change that passes the checks but whose render fails (here a MemoryError the estimate
    did not foresee) is undone: /api/state and the frame as before, X-Frame-Error on the frame
    that undid it only."""
    v = surface_viewer
    real = v.adapter.render

    def render(size, preview=False):
        if v.adapter.pipe.params.photons == 3000:
            raise MemoryError("std::bad_alloc")
        return real(size, preview)

    monkeypatch.setattr(v.adapter, "render", render)
    with TestClient(create_app(v), base_url="http://127.0.0.1",
                    headers={"X-Photonmap-Token": v.token}) as client:  # fmt: skip
        before = client.get("/api/state").json()
        first = client.get("/api/frame.png")
        assert client.post("/api/update", json={"params": {"photons": 3000}}).status_code == 200
        undone = client.get("/api/frame.png")
        assert undone.headers["X-Frame-Error"] == "MemoryError: std::bad_alloc"
        assert client.get("/api/state").json() == before
        np.testing.assert_array_equal(pixels(undone.content), pixels(first.content))
        assert client.post("/api/update", json={"params": {"photons": 2500}}).status_code == 200
        later = client.get("/api/frame.png")
        assert later.status_code == 200 and "X-Frame-Error" not in later.headers
        assert client.get("/api/state").json()["params"]["photons"] == 2500
