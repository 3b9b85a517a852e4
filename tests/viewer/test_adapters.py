"""The screen and surface adapters (the viewer's handles on those pipelines): each change the page
can make gives the image the package API gives for the same change, and reruns only what it
must (a camera move keeps the photons)."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from photonmap import ParameterError, ScreenPipeline, SurfacePipeline
from photonmap.viewer.mitsuba_adapters import ScreenAdapter, SurfaceAdapter
from photonmap.viewer.state import changes

SMALL = (48, 36)
SURFACE = {"photons": 2000, "caustic_photons": 4000, "fg_rays": 4}


def change(adapter, update):
    new = adapter.check(adapter.state, update)
    adapter.apply(changes(adapter.state, new), new)
    return np.asarray(adapter.render(SMALL))


def drag(adapter, update, stage):
    """``update`` as a drag makes it: a ¼-size preview, then the full frame (returned). The
    preview reruns ``stage`` with each of the adapter's budget parameters divided, the full
    frame with the user's (the state never changes them)."""
    params = dict(adapter.state["params"])
    new = adapter.check(adapter.state, update)
    adapter.apply(changes(adapter.state, new), new)
    adapter.render((SMALL[0] // 4, SMALL[1] // 4), preview=True)
    reduced = {k: params[k] // d for k, d in adapter.preview_divisors.items()}
    assert adapter.reduced == reduced and stage in adapter.recomputed
    assert {k: getattr(adapter.pipe.params, k) for k in reduced} == reduced
    image = np.asarray(adapter.render(SMALL))
    assert adapter.reduced == {} and stage in adapter.recomputed
    assert adapter.state["params"] == params
    return image


def set_eta(pipe, name, eta):
    shape = next(s for s in pipe.scene.shapes() if s.id() == name)
    params = mi.traverse(shape.bsdf())
    params["eta"] = eta
    params.update()


def test_screen_light_material_camera():
    a = ScreenAdapter("screen", "cornell_glass_sphere", {"photons": 16**2, "subsample": 2}, SMALL)
    assert a.state["materials"] == {"glass_sphere": {"ior": 1.5}}
    assert a.state["lights"][0]["kind"] == "spot" and len(a.state["lights"]) == 1
    a.render(SMALL)
    moved = change(a, {"lights": [{"position": [0.2, 0.5, 0.3], "intensity": 1.0}]})
    assert "eye G-buffer" not in a.recomputed and "light G-buffer" in a.recomputed
    ref = ScreenPipeline("cornell_glass_sphere", photons=16**2, subsample=2)
    ref.set_camera(width=SMALL[0], height=SMALL[1])
    color = np.asarray(a.state["lights"][0]["color"])
    ref.set_light(position=[0.2, 0.5, 0.3], intensity=color * 1.0)
    np.testing.assert_array_equal(moved, np.asarray(ref.render()))
    glass = change(a, {"materials": {"glass_sphere": {"ior": 1.2}}})
    set_eta(ref, "glass_sphere", 1.2)
    ref.invalidate()
    np.testing.assert_array_equal(glass, np.asarray(ref.render()))
    dragged = drag(a, {"lights": [{"position": [0.1, 0.5, 0.2]}]}, "photon tracing")
    ref.set_light(position=[0.1, 0.5, 0.2])
    np.testing.assert_array_equal(dragged, np.asarray(ref.render()))
    change(a, {"camera": {"origin": [0.3, 0.3, -0.7]}})
    assert "light G-buffer" not in a.recomputed and "photon tracing" not in a.recomputed
    with pytest.raises(ParameterError, match="photons must be >= 1"):
        a.check(a.state, {"params": {"photons": 0}})


def test_surface_light_material_camera():
    a = SurfaceAdapter("surface", "cornell_steinhurst", dict(SURFACE), SMALL)
    assert set(a.state["materials"]) == {"glass_sphere"}
    assert [light["kind"] for light in a.state["lights"]] == ["area"]
    assert "position" not in a.state["lights"][0]  # area lights move with their shape
    a.render(SMALL)
    brighter = drag(a, {"lights": [{"intensity": 2 * a.state["lights"][0]["intensity"]}],
                        "materials": {"glass_sphere": {"ior": 1.3}}}, "photon maps")  # fmt: skip
    assert "photon maps" in a.recomputed
    ref = SurfacePipeline("cornell_steinhurst", **SURFACE)
    ref.set_camera(width=SMALL[0], height=SMALL[1])  # as the viewer and `photonmap render` do
    params = mi.traverse(next(e for e in ref.scene.emitters() if e.class_name() == "AreaLight"))
    radiance = 2 * np.array(params["radiance.value"]).ravel()
    params["radiance.value"] = mi.Color3f(*radiance.tolist())
    params.update()
    set_eta(ref, "glass_sphere", 1.3)
    sensor = ref.sensor
    ref = SurfacePipeline(ref.scene, **SURFACE)  # photon maps traced on the edited scene
    ref.set_camera(sensor=sensor)
    np.testing.assert_allclose(brighter, np.asarray(ref.render()), atol=1e-5, rtol=1e-4)
    change(a, {"camera": {"origin": [0.3, 0.3, -0.7]}})
    assert "photon maps" not in a.recomputed and "eye pass" in a.recomputed


def test_surface_spot_position():
    a = SurfaceAdapter("surface", "cornell_spot_indirect", dict(SURFACE), SMALL)
    before = a.render(SMALL).copy()
    position = np.add(a.state["lights"][0]["position"], [0.1, 0.0, 0.05])
    moved = change(a, {"lights": [{"position": position.tolist()}]})
    emitter = next(e for e in a.pipe.scene.emitters() if e.class_name() == "SpotLight")
    m = np.array(mi.traverse(emitter)["to_world"].matrix, float).reshape(4, 4)
    np.testing.assert_allclose(m[:3, 3], position, atol=1e-6)
    assert np.abs(moved - before).mean() > 1e-4


class SteppedScreen(ScreenPipeline):
    """A pipeline that refines itself, as the sppm method does (``progressive``: ``reset``,
    ``step``, ``image``): each step adds a render with the next seed to a running mean."""

    progressive = True

    def reset(self):
        self.iterations, self._sum = 0, None

    def step(self):
        self.set_params(seed=self.iterations)
        image = np.asarray(self.render())
        self._sum = image if self._sum is None else self._sum + image
        self.iterations += 1

    def image(self):
        return mi.TensorXf(self._sum / self.iterations)


def test_a_self_refining_method_steps_while_idle_and_restarts(monkeypatch):
    import time

    import photonmap
    from photonmap.viewer import Viewer, adapters, methods

    monkeypatch.setitem(photonmap.METHODS, "stepped", photonmap.METHODS["screen"]._replace(
        pipeline=SteppedScreen))  # fmt: skip
    monkeypatch.setitem(methods.ADAPTERS, "stepped",
                        adapters.progressive(ScreenAdapter, ("bounces",)))  # fmt: skip
    monkeypatch.setattr(adapters, "MAX_PASSES", 2)
    viewer = Viewer("cornell_ispm", "stepped", {"photons": 16**2, "subsample": 2}, SMALL)
    try:
        assert viewer.state()["params"] == {"bounces": 0}  # 0: the file's max_depth − 2
        worker, pipe = viewer.worker, viewer.adapter.pipe
        worker.wait_frame()
        deadline = time.monotonic() + 300  # a guard against a hang, not a speed bound
        while worker.frame.passes < 3 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert worker.frame.passes == 3 and pipe.iterations == 3  # then no more (MAX_PASSES)
        renders = []
        for seed in range(3):
            ref = ScreenPipeline("cornell_ispm", photons=16**2, subsample=2, seed=seed)
            ref.set_camera(width=SMALL[0], height=SMALL[1])
            renders.append(np.asarray(ref.render()))
        np.testing.assert_allclose(np.asarray(pipe.image()), np.mean(renders, axis=0), rtol=1e-5,
                                   atol=1e-6)  # fmt: skip
        shown = []  # every frame from now on (the render thread may refine past the first
        worker.subscribe(lambda _meta, frame: frame and shown.append(frame))  # before we look)
        worker.update({"camera": {"origin": [0.3, 0.3, -0.7]}})
        frame = worker.wait_frame()
        first = next(f for f in shown if f.version == frame.version and not f.preview)
        assert first.passes == 1 and pipe.iterations >= 1  # restarted, refining again
    finally:
        viewer.close()


def test_a_preview_budget_the_method_refuses_stays_the_users():
    """Adaptive emission needs more photons than pilots (Pfeuti §3.2): 128²/16 = 32² pilots is
    refused, so the preview of a light drag traces the user's 128² photons."""
    from photonmap.viewer.volume_adapter import VolumeAdapter

    overrides = {"grid": 16, "photons": 128**2, "emission": "adaptive", "pilot_photons": 32**2}
    a = VolumeAdapter("volume", "glass_sphere_fog", overrides, (16, 12))
    new = a.check(a.state, {"lights": [{"intensity": 20}]})
    a.apply(changes(a.state, new), new)
    a.render((8, 8), preview=True)
    assert a.reduced == {} and a.pipe.params.photons == 128**2
