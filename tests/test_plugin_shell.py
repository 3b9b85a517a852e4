"""The plugin shell shared by ``volume_photon``, ``photon_mapper`` and ``ispm``
(:mod:`photonmap.core.plugin`): one pipeline per scene, edits through ``mi.traverse`` seen."""

import numpy as np
import pytest

from photonmap import mi
from photonmap.core.plugin import PipelineIntegrator, scene_fingerprint
from photonmap.scenes import SCENES

SMALL = {
    "volume_photon": {"grid": 24, "photons": 4096},
    "photon_mapper": {"photons": 4000, "caustic_photons": 4000, "fg_rays": 2, "emitter_spp": 1},
    "ispm": {"photons": 16**2, "subsample": 2},
}


def _scene(plugin: str) -> tuple[mi.Scene, str]:
    """A small scene the plugin accepts and the key of its light's radiance or intensity."""
    if plugin == "volume_photon":
        return mi.load_dict(SCENES["glass_sphere_fog"].build(width=16, height=12)), "intensity"
    box = mi.cornell_box()
    box["sensor"]["film"].update(width=16, height=16)
    return mi.load_dict(box), "radiance"


@pytest.mark.parametrize("plugin", sorted(SMALL))
def test_a_traverse_edit_of_the_light_reaches_the_image(plugin):
    """Doubling a light's radiance in place doubled the photon mapper's image
    only ×1.74 and left the ispm image unchanged (stale photons)."""
    scene, what = _scene(plugin)
    integ = mi.load_dict({"type": plugin, **SMALL[plugin]})
    assert isinstance(integ, PipelineIntegrator)
    before = np.array(mi.render(scene, integrator=integ), dtype=np.float64)
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith(f"{what}.value"))
    params[key] = params[key] * 2
    params.update()
    after = np.array(mi.render(scene, integrator=integ), dtype=np.float64)
    assert before.mean() > 0
    assert after.sum() / before.sum() == pytest.approx(2.0, rel=1e-4)


def test_the_fingerprint_sees_shapes_and_emitters_not_sensors():
    scene, _ = _scene("photon_mapper")
    first = scene_fingerprint(scene)
    params = mi.traverse(scene)
    params["sensor.x_fov"] = 30.0
    params.update()
    assert scene_fingerprint(scene) == first  # a camera move keeps the photons
    key = next(k for k in params.keys() if k.endswith("reflectance.value"))
    params[key] = params[key] * 0.5
    params.update()
    assert scene_fingerprint(scene) != first


def test_every_method_is_exported_with_its_stages():
    import photonmap

    for name, method in photonmap.METHODS.items():
        assert method.params in (photonmap.VolumeParams, photonmap.SurfaceParams,
                                 photonmap.ScreenParams, photonmap.SPPMParams,
                                 photonmap.VCMParams)  # fmt: skip
        assert hasattr(method.pipeline, "stages"), name
    assert photonmap.SurfacePipeline.stages == photonmap.SURFACE_STAGES


def test_the_fingerprint_reads_scenes_with_unset_parameters():
    """The ``hair`` BSDF leaves ``sigma_a`` unset when pigments colour it: Mitsuba raises a
    TypeError when it is read, and the fingerprint passes over it."""
    scene = mi.load_dict({"type": "scene", "ball": {"type": "sphere", "bsdf": {"type": "hair"}},
                          "light": {"type": "constant"}})  # fmt: skip
    first = scene_fingerprint(scene)
    params = mi.traverse(scene)
    params["ball.bsdf.eumelanin"] = 0.5
    params.update()
    assert scene_fingerprint(scene) != first
