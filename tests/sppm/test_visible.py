"""The SPPM eye pass's emission seen (:mod:`photonmap.sppm.visible`): traced only on the pixels
that can see a light through mirrors and glass (and within the film filter's reach of them),
it is the estimate of tracing every pixel, bit for bit."""

import mitsuba as mi
import numpy as np
import pytest

from photonmap.sppm import visible
from photonmap.sppm.pipeline import SPPMPipeline


def cornell_glass(rfilter: str) -> mi.Scene:
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=40, height=32, rfilter={"type": rfilter})
    d["glass"] = {"type": "sphere", "center": [0.3, -0.6, 0.2], "radius": 0.35,
                  "bsdf": {"type": "dielectric"}}  # fmt: skip
    d["mirror"] = {"type": "sphere", "center": [-0.4, -0.7, -0.3], "radius": 0.3,
                   "bsdf": {"type": "conductor"}}  # fmt: skip
    return mi.load_dict(d)


@pytest.mark.parametrize("rfilter", ["box", "gaussian"])
def test_the_pixels_traced_give_the_whole_image(rfilter, monkeypatch):
    traced = {}
    whole = visible.emission_seen

    def both(scene, sensor, seed, settings, traits, pixels, only=None):
        full = np.array(whole(scene, sensor, seed, settings, traits, pixels))
        part = np.array(whole(scene, sensor, seed, settings, traits, pixels, only))
        traced.setdefault("runs", []).append((full, part, len(only), pixels))
        return mi.Color3f(part)

    monkeypatch.setattr(visible, "emission_seen", both)
    SPPMPipeline(cornell_glass(rfilter), iterations=2, photons=1000, seed=1).render()
    for full, part, count, pixels in traced["runs"]:
        assert full.max() > 0  # the light and its images are seen
        np.testing.assert_array_equal(part, full)
        assert count < pixels / 2  # most pixels see a diffuse wall first
