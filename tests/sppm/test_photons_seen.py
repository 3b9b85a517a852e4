"""``SPPMPipeline.photons_seen``, the share of an iteration's photons that lie within some visible
point's gather radius, and the rays the passes report (the benchmarks' diagnostics): every photon
where the radius spans the scene, almost none where it is a speck, in between at the automatic
radius; the next iteration traced for it is not kept."""

import mitsuba as mi
import numpy as np
import pytest

from photonmap.sppm import SPPMPipeline


def glass_cornell() -> mi.Scene:
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=32, height=32)
    del d["small-box"], d["large-box"]
    d["ball"] = {"type": "sphere", "center": [0.3, -0.7, 0.2], "radius": 0.25,
                 "bsdf": {"type": "dielectric"}}  # fmt: skip
    return mi.load_dict(d)


@pytest.mark.parametrize(("radius", "low", "high"), [(10.0, 1.0, 1.0), (1e-5, 0.0, 0.01),
                                                     (0.0, 0.05, 0.95)])  # fmt: skip
def test_the_share_of_photons_within_a_gather_radius(radius, low, high):
    pipe = SPPMPipeline(glass_cornell(), seed=2, photons=5000, radius=radius, transport="photons")
    pipe.step()
    before = np.array(pipe.image())
    assert low <= pipe.photons_seen() <= high
    assert pipe.iterations == 1 and np.array_equal(np.array(pipe.image()), before)


def test_the_passes_count_their_rays():
    pipe = SPPMPipeline(glass_cornell(), seed=2, photons=5000, transport="photons")
    pipe.step()
    s = pipe.stats
    assert s["photons"] <= s["photon_rays"] <= s["photons"] * 12  # one to max_depth per path
    assert s["gathers"] < s["eye_rays"] < s["gathers"] * 24  # segments, shadow rays, light paths


def test_path_traced_iterations_have_no_visible_points():
    pipe = SPPMPipeline(glass_cornell(), seed=2, photons=5000, transport="paths")
    pipe.step()
    assert pipe.photons_seen() is None
