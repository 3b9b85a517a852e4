"""The viewer's HTTP API on a small glass_sphere_fog: every endpoint, bad input
(422 with the reason, state unchanged), and the images against the oracle — the same changes
made through the package API (conftest.direct)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from viewer_oracle import OVERRIDES, SCENE, SIZE, direct, pixels

LIGHT_STAGES = ["photon generation", "photon tracing", "smoothing", "view grids", "viewing"]


def test_state_round_trip_and_first_frame(client):
    state = client.get("/api/state").json()
    assert state["scene"] == SCENE and state["method"] == "volume"
    assert set(state) >= {"camera", "lights", "materials", "params", "stages"}
    assert state["camera"]["width"] == SIZE[0] and state["camera"]["height"] == SIZE[1]
    assert state["lights"][0]["kind"] == "point" and state["params"]["photons"] == 64**2
    assert set(state["materials"]) == {"glass", "fog"}
    # GET's document is what POST takes: sending it back changes nothing
    reply = client.post("/api/update", json=state)
    assert reply.status_code == 200, reply.text
    assert reply.json()["state"] == state
    np.testing.assert_array_equal(pixels(client.get("/api/frame.png").content), direct())


def test_light_move_reruns_the_light_stages_and_matches_the_api(client):
    before = pixels(client.get("/api/frame.png").content)
    position, color = [0.3, 3.0, 0.6], [1.0, 0.5, 0.25]
    reply = client.post("/api/update", json={"lights": [{"position": position, "color": color,
                                                         "intensity": 60}]})  # fmt: skip
    assert reply.status_code == 200, reply.text
    png = client.get("/api/frame.png")
    assert int(png.headers["X-Frame-Version"]) == reply.json()["version"]
    meta = client.get("/api/frame.json").json()
    assert meta["recomputed"] == LIGHT_STAGES and set(meta["timings"]) == set(LIGHT_STAGES)
    image = pixels(png.content)
    assert np.abs(image.astype(int) - before).mean() > 1
    expected = direct(lambda p: p.set_light(0, position=position, intensity=[60, 30, 15]))
    np.testing.assert_array_equal(image, expected)
    # lights addressed as an object of indices
    assert client.post("/api/update", json={"lights": {"0": {"intensity": 10}}}).status_code == 200
    assert client.get("/api/state").json()["lights"][0]["intensity"] == 10


def test_camera_move_reruns_the_viewing_pass_only(client):
    client.get("/api/frame.png")
    camera = {"origin": [0.5, 0.9, 2.6], "target": [0.5, 0.4, 0.5], "fov": 45}
    assert client.post("/api/update", json={"camera": camera}).status_code == 200
    image = pixels(client.get("/api/frame.png").content)
    assert client.get("/api/frame.json").json()["recomputed"] == ["viewing"]
    np.testing.assert_array_equal(image, direct(lambda p: p.set_camera(**camera)))


def test_material_and_params(client):
    update = {"materials": {"glass": {"ior": 1.3}, "fog": {"sigma_s": 0.5}},
              "params": {"photons": 96**2, "emission": "adaptive"}}  # fmt: skip
    assert client.post("/api/update", json=update).status_code == 200, "accepted"
    image = pixels(client.get("/api/frame.png").content)
    state = client.get("/api/state").json()
    assert state["materials"]["fog"]["sigma_s"] == [0.5] * 3
    assert state["params"] == {"photons": 96**2, "emission": "adaptive"}

    def edit(p):
        p.set_material("glass", ior=1.3)
        p.set_material("fog", sigma_s=0.5)
        p.set_params(photons=96**2, emission="adaptive")

    np.testing.assert_array_equal(image, direct(edit))


BAD = [
    ({"lights": [{}, {"intensity": 1}]}, "the scene has 1"),
    ({"lights": {"3": {"intensity": 1}}}, "no light '3'"),
    ({"lights": [{"position": [0, 1]}]}, "lights[0].position must be 3 numbers"),
    ({"lights": [{"position": ["a", 0, 0]}]}, "lights[0].position must be 3 numbers"),
    ({"lights": [{"intensity": -1}]}, "lights[0].intensity must be >= 0"),
    ({"lights": [{"color": [1, -1, 0]}]}, "must be >= 0 in every channel"),
    ({"lights": [{"kind": "spot"}]}, "read-only"),
    ({"lights": [{"size": 3}]}, "unknown key(s) size in lights[0]"),
    ({"materials": {"glass": {"ior": 0.5}}}, "must be >= 1"),
    ({"materials": {"glass": {"ior": True}}}, "must be a number"),
    ({"materials": {"fog": {"ior": 1.2}}}, "unknown key(s) ior in materials.fog"),
    ({"materials": {"marble": {"ior": 1.2}}}, "no material 'marble'"),
    ({"params": {"photons": -5}}, "photons"),
    ({"params": {"emission": "magic"}}, "emission must be one of uniform, adaptive"),
    ({"params": {"grid": 64}}, "unknown key(s) grid in params"),
    ({"camera": {"origin": [0.5, 0.5, 0.5], "target": [0.5, 0.5, 0.5]}}, "must differ"),
    ({"camera": {"fov": 200}}, "camera.fov must be <= 180"),
    ({"camera": {"width": 0}}, "camera.width must be >= 1"),
    ({"camera": {"width": 9.5}}, "camera.width must be an integer"),
    ({"scene": "cornell_ispm"}, "scene is read-only"),
    ({"volume": {"frame": 0}}, "no volume sequence"),
    ({"preview": "yes"}, "preview must be true or false"),
    ({"colour": 1}, "unknown key(s) colour"),
    # a valid camera with a bad light: refused whole
    ({"camera": {"fov": 30}, "lights": [{"intensity": -1}]}, "intensity must be >= 0"),
    ([1, 2], "an update must be a JSON object"),
]


@pytest.mark.parametrize("body,reason", BAD, ids=[str(b)[:40] for b, _ in BAD])
def test_bad_update_is_422_and_changes_nothing(client, body, reason):
    before = client.get("/api/state").json()
    reply = client.post("/api/update", json=body)
    assert reply.status_code == 422
    assert reason in reply.json()["detail"]
    assert client.get("/api/state").json() == before


def test_bad_bodies(client):
    reply = client.post("/api/update", content=b"{not json",
                        headers={"content-type": "application/json"})  # fmt: skip
    assert reply.status_code == 422 and "not valid JSON" in reply.json()["detail"]
    for stroke, reason in [
        ({"center": [0, 0, 0], "radius": 0, "amount": 1}, "stroke.radius must be > 0"),
        ({"center": [0, 0, 0], "radius": 1}, "a stroke needs amount"),
        ({"center": [0, 0, 0], "radius": 1, "amount": 1, "field": "rho"}, "'sigma_s' or 'n'"),
    ]:
        reply = client.post("/api/paint", json=stroke)
        assert reply.status_code == 422 and reason in reply.json()["detail"]


def test_paint_and_reset(client, viewer):
    original = pixels(client.get("/api/frame.png").content)
    stroke = {"field": "sigma_s", "center": [0.5, 0.25, 0.5], "radius": 0.08, "amount": 20}
    assert client.post("/api/paint", json=stroke).status_code == 200
    painted = pixels(client.get("/api/frame.png").content)
    # the brush: σ_s (and κ, σ_a kept) raised by a Gaussian of 20 / unit at the stroke's centre
    grids = viewer.adapter.pipe.world.grids
    own = viewer.adapter.own_grids()
    i = tuple(int(c) for c in viewer.adapter.pipe.world.box.to_voxel(stroke["center"]))[::-1]
    added = grids["sigma_s"][i] - own["sigma_s"][i]
    assert added == pytest.approx(np.full(3, 20 * np.exp(-0.5 * 0.75 / (0.08 * 32) ** 2)), rel=1e-3)
    np.testing.assert_allclose(grids["kappa"][i] - own["kappa"][i], added, rtol=1e-5)
    assert np.abs(painted.astype(int) - original).mean() > 0.5
    np.testing.assert_array_equal(
        painted, direct(lambda p: p.set_volume(**{k: np.asarray(v) for k, v in grids.items()}))
    )
    n_stroke = {**stroke, "field": "n", "amount": 0.2}
    assert client.post("/api/paint", json=n_stroke).status_code == 200
    client.get("/api/frame.png")
    assert viewer.adapter.pipe.world.grids["n"][i] > own["n"][i] + 0.1
    assert client.post("/api/reset").status_code == 200
    np.testing.assert_array_equal(pixels(client.get("/api/frame.png").content), original)


def test_volume_sequence(tmp_path):
    from fastapi.testclient import TestClient

    from photonmap import ParameterError
    from photonmap.viewer import Viewer, create_app

    n = OVERRIDES["grid"]
    z, y, x = np.meshgrid(*[np.arange(n)] * 3, indexing="ij")
    blobs = [np.exp(-((x - c) ** 2 + (y - 8) ** 2 + (z - 16) ** 2) / 20.0) for c in (10, 22)]
    frames = {"sigma_s": np.stack([40 * b for b in blobs]).astype(np.float32)}
    with pytest.raises(ParameterError, match=r"expected \(F, 32, 32, 32"):
        Viewer(SCENE, "volume", dict(OVERRIDES), SIZE, frames={"kappa": np.zeros((2, 8, 8, 8))})
    viewer = Viewer(SCENE, "volume", dict(OVERRIDES), SIZE, frames=frames)
    try:
        with TestClient(create_app(viewer), base_url="http://127.0.0.1",
                        headers={"X-Photonmap-Token": viewer.token}) as client:  # fmt: skip
            assert client.get("/api/state").json()["frames"] == 2
            own = viewer.adapter.own_grids() if client.get("/api/frame.png") else None
            images = []
            for k in (0, 1):
                assert client.post("/api/update", json={"volume": {"frame": k}}).status_code == 200
                images.append(pixels(client.get("/api/frame.png").content))
            reply = client.post("/api/update", json={"volume": {"frame": 2}})
            assert reply.status_code == 422 and "volume.frame must be <= 1" in reply.text
    finally:
        viewer.close()
    assert np.abs(images[0].astype(int) - images[1]).mean() > 0.5
    kappa = frames["sigma_s"][1][..., None] + np.maximum(own["kappa"] - own["sigma_s"], 0)
    expected = direct(lambda p: p.set_volume(n=own["n"], sigma_s=frames["sigma_s"][1],
                                             kappa=kappa))  # fmt: skip
    np.testing.assert_array_equal(images[1], expected)


def test_stream_sends_meta_then_the_image(client):
    png = client.get("/api/frame.png").content
    token = client.headers["x-photonmap-token"]
    with client.websocket_connect(f"ws://127.0.0.1/api/stream?token={token}") as ws:
        meta = ws.receive_json()
        data = ws.receive_bytes()
    assert meta["type"] == "frame" and not meta["preview"] and meta["mime"] == "image/jpeg"
    assert (meta["width"], meta["height"]) == SIZE and set(meta["recomputed"]) <= set(
        client.get("/api/state").json()["stages"]
    )
    # the streamed JPEG (quality 92) is the frame within JPEG's error: measured mean 0.77 / 255
    assert np.abs(pixels(data).astype(int) - pixels(png)).mean() < 1.5


def test_updates_coalesce_newest_wins(viewer):
    """Five updates while the render thread is busy give one frame, of the last state."""
    worker = viewer.worker
    worker.wait_frame()
    seq = worker.frame.seq
    metas = []
    worker.subscribe(lambda meta, frame: metas.append(meta))
    busy, release = threading.Event(), threading.Event()
    worker.act(lambda: (busy.set(), release.wait(30)))
    assert busy.wait(30)
    for intensity in (10, 20, 30, 40, 50):
        worker.update({"lights": [{"intensity": intensity}]})
    release.set()
    frame = worker.wait_frame()
    # the action's own frame saw versions up to the act; the five updates make one frame more
    assert [m["version"] for m in metas][-1] == worker.version == frame.version
    assert frame.seq - seq == 2 and len(metas) == 2
    np.testing.assert_array_equal(frame.pixels, direct(lambda p: p.set_light(0, intensity=50)))


def test_a_frame_reaches_the_listeners_before_wait_frame_returns(viewer):
    """A subscriber (the page's stream, a script) has seen every frame ``wait_frame`` returns,
    however slow it is."""
    worker = viewer.worker
    worker.wait_frame()
    seen = []
    worker.subscribe(lambda meta, frame: (time.sleep(0.2), seen.append(meta["version"])))
    _, version = worker.update({"lights": [{"intensity": 20}]})
    assert worker.wait_frame(version).version == version
    assert seen and seen[-1] == version


def test_preview_then_full_resolution(viewer):
    worker = viewer.worker
    worker.wait_frame()
    metas = []
    worker.subscribe(lambda meta, frame: metas.append(meta))
    worker.update({"camera": {"origin": [1.5, 1.0, 2.0]}, "preview": True})
    frame = worker.wait_frame()
    assert [(m["preview"], m["width"], m["height"]) for m in metas] == [
        (True, SIZE[0] // 4, SIZE[1] // 4), (False, *SIZE)
    ]
    assert metas[0]["mime"] == "image/jpeg" and metas[1]["recomputed"] == ["viewing"]
    np.testing.assert_array_equal(
        frame.pixels, direct(lambda p: p.set_camera(origin=[1.5, 1.0, 2.0], target=
                                                    worker.target["camera"]["target"]))
    )


def test_light_drag_previews_fewer_photons_then_the_full_render(viewer, client):
    """A light dragged (preview updates): the preview frame retraces 1/16 of the photons at ¼
    size, the full frame when the drag stops is a fresh render of the full settings, and the
    state keeps the user's photon count throughout; a camera drag then keeps the photons."""
    worker, photons = viewer.worker, OVERRIDES["photons"]
    worker.wait_frame()
    frames = []
    worker.subscribe(lambda meta, frame: frames.append((meta, frame)))
    position = [0.4, 3.0, 0.6]
    update = {"lights": [{"position": position, "intensity": 40}], "preview": True}
    assert client.post("/api/update", json=update).status_code == 200
    worker.wait_frame()
    assert client.get("/api/state").json()["params"]["photons"] == photons
    (preview, small), (full, frame) = frames
    assert preview["preview"] and preview["reduced"] == {"photons": photons // 16}
    assert "photon tracing" in preview["recomputed"] and small.pixels.shape[:2] == (18, 24)
    assert not full["preview"] and full["reduced"] == {} and "photon tracing" in full["recomputed"]

    def moved(pipe, budget=photons):
        pipe.set_params(photons=budget)
        pipe.set_light(0, position=position, intensity=[40, 40, 40])

    np.testing.assert_array_equal(small.pixels, direct(lambda p: moved(p, photons // 16),
                                                       size=(24, 18)))  # fmt: skip
    np.testing.assert_array_equal(frame.pixels, direct(moved))
    frames.clear()
    worker.update({"camera": {"origin": [1.5, 1.0, 2.0]}, "preview": True})
    worker.wait_frame()
    assert [(m["reduced"], m["recomputed"]) for m, _ in frames] == [({}, ["viewing"])] * 2


def test_progressive_method_refines_and_restarts(monkeypatch):
    """How an sppm method is offered: refine while idle (the mean of renders with seeds 0, 1,
    2, ...), restart on any change."""
    from photonmap import VolumePipeline
    from photonmap.viewer import Viewer, adapters, methods
    from photonmap.viewer.volume_adapter import VolumeAdapter
    from photonmap.viewer.worker import to_srgb8

    monkeypatch.setattr(adapters, "MAX_PASSES", 2)
    monkeypatch.setitem(methods.ADAPTERS, "volume", adapters.progressive(VolumeAdapter))
    viewer = Viewer(SCENE, "volume", dict(OVERRIDES), SIZE)
    try:
        worker = viewer.worker
        metas = []
        worker.subscribe(lambda meta, frame: metas.append(meta))
        worker.wait_frame()
        deadline = time.monotonic() + 300  # a guard against a hang, not a speed bound
        while worker.frame.passes < 3 and time.monotonic() < deadline:
            time.sleep(0.05)
        renders = [
            VolumePipeline(SCENE, **OVERRIDES, width=SIZE[0], height=SIZE[1], seed=s).render()
            for s in range(3)
        ]
        mean = to_srgb8(np.mean([np.asarray(r) for r in renders], axis=0))
        assert np.abs(worker.frame.pixels.astype(int) - mean).max() <= 1  # float32 rounding
        worker.update({"lights": [{"intensity": 20}]})
        frame = worker.wait_frame()
        assert frame.passes == 1 and frame.recomputed[0] == "photon generation"
        assert [m["passes"] for m in metas][-3:] == [2, 3, 1]  # no fourth pass: MAX_PASSES
    finally:
        viewer.close()


def test_a_change_the_pipeline_refuses_is_undone_and_reported(viewer, monkeypatch):
    """An update that passes the checks but that the pipeline refuses (a setter raising after
    the camera part was applied) is undone whole: the state and the frame are those before it,
    and the reason comes once, on the stream and on the frame that undid it."""
    from photonmap import ParameterError

    worker = viewer.worker
    before = worker.wait_frame()
    state0 = worker.target_state()
    pipe = viewer.adapter.pipe
    real = pipe.set_params

    def refuse(**params):
        if params.get("photons") == 8192:
            raise ParameterError("photons=8192 refused by the pipeline")
        real(**params)

    monkeypatch.setattr(pipe, "set_params", refuse)
    errors = []
    worker.subscribe(lambda meta, frame: meta["type"] == "error" and errors.append(meta))
    camera = {"origin": [0.5, 0.9, 2.6], "target": [0.5, 0.4, 0.5]}
    worker.update({"camera": camera, "params": {"photons": 8192}})
    frame = worker.wait_frame()
    assert len(errors) == 1 and "refused by the pipeline" in errors[0]["message"]
    assert frame.error == errors[0]["message"] and frame.meta()["error"] == frame.error
    assert worker.target_state() == state0  # the camera part too
    # the frame rendered again: equal up to 8-bit rounding of a few pixels (the photon grids'
    # atomic float sums are not bit-reproducible across renders)
    diff = np.abs(frame.pixels.astype(int) - before.pixels.astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 1e-3
    worker.update({"camera": camera})  # a good change after it: no stale error
    frame = worker.wait_frame()
    assert frame.error is None
    np.testing.assert_array_equal(frame.pixels, direct(lambda p: p.set_camera(**camera)))


def test_a_closed_viewer_leaves_nothing_in_later_kernels():
    """FastAPI caches the routes of every application it served, and they hold the viewer. A
    closed viewer must not hold its scene: the scene's BSDFs, shapes and emitters would stay in
    Dr.Jit's registry, where every later symbolic call traces them too — a render of another
    scene would compile a new kernel (and trace ever more slowly) after each viewer."""
    import drjit as dr
    import mitsuba as mi
    from fastapi.testclient import TestClient

    from photonmap.viewer import Viewer, create_app

    other = mi.load_dict(mi.cornell_box())

    def kernels() -> tuple:
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
            dr.kernel_history()
            np.array(mi.render(other, spp=1))
            return tuple(k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT)

    before = kernels()
    viewer = Viewer(SCENE, "volume", dict(OVERRIDES), SIZE)
    with TestClient(create_app(viewer), base_url="http://127.0.0.1",
                    headers={"X-Photonmap-Token": viewer.token}) as client:  # fmt: skip
        assert client.get("/api/frame.png").status_code == 200
        assert kernels() != before  # the open viewer's scene is in the calls: the check can fail
    viewer.close()
    assert kernels() == before
