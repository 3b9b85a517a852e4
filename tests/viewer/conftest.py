"""Fixtures of the viewer tests: the viewer of :mod:`viewer_oracle`'s scene, a test client, and a
uvicorn server on a free port for the browser tests."""

from __future__ import annotations

import os
import sys

import pytest

pytest.importorskip("fastapi", reason="the viewer extra is not installed: pip install .[viewer]")
sys.path.insert(0, os.path.dirname(__file__))

from viewer_oracle import OVERRIDES, SCENE, SIZE  # noqa: E402


@pytest.fixture
def viewer():
    from photonmap.viewer import Viewer

    v = Viewer(SCENE, "volume", dict(OVERRIDES), SIZE)
    yield v
    v.close()


@pytest.fixture
def client(viewer):
    from fastapi.testclient import TestClient

    from photonmap.viewer import create_app

    with TestClient(create_app(viewer), base_url="http://127.0.0.1",
                    headers={"X-Photonmap-Token": viewer.token}) as c:  # fmt: skip
        yield c


@pytest.fixture(scope="module")
def server():
    """The viewer served by uvicorn on a free port of 127.0.0.1: (base URL, viewer)."""
    from photonmap.viewer import Background, Viewer

    with Background(Viewer(SCENE, "volume", dict(OVERRIDES), SIZE)) as bg:
        yield bg.url.rstrip("/"), bg.viewer
