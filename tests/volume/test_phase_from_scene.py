"""The volume method takes the fog's phase function from the Mitsuba scene:
isotropic → Schlick k = 0, Henyey–Greenstein g → k = 1.55 g − 0.55 g³; ``phase_k`` overrides."""

import numpy as np
import pytest

from photonmap import VolumePipeline, mi
from photonmap.core.errors import SceneError
from photonmap.core.params import field_types
from photonmap.volume.params import VolumeParams

SMALL = {"grid": 16, "photons": 1024}


def mean(image) -> float:
    return float(np.asarray(image).mean())


def fog_box(phase: dict | None) -> mi.Scene:
    fog = {"type": "homogeneous", "sigma_t": 0.5, "albedo": 0.8}
    if phase is not None:
        fog["phase"] = phase
    return mi.load_dict(
        {
            "type": "scene",
            "sensor": {
                "type": "perspective",
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]
                ),
                "film": {"type": "hdrfilm", "width": 16, "height": 12},
            },
            "box": {"type": "cube", "bsdf": {"type": "null"}, "interior": fog},
            "lamp": {"type": "point", "position": [0, 3, 0], "intensity": 10.0},
        }
    )


@pytest.mark.parametrize(
    ("phase", "k"),
    [
        (None, 0.0),  # Mitsuba's default phase function is isotropic
        ({"type": "isotropic"}, 0.0),
        ({"type": "hg", "g": 0.6}, 1.55 * 0.6 - 0.55 * 0.6**3),
        ({"type": "hg", "g": -0.3}, 1.55 * -0.3 - 0.55 * (-0.3) ** 3),
    ],
)
def test_schlick_k_comes_from_the_fogs_phase_function(phase, k):
    pipe = VolumePipeline(fog_box(phase), **SMALL)
    assert pipe.phase_k == pytest.approx(k, abs=1e-6)
    image = pipe.render()
    assert mean(image) > 0
    assert VolumePipeline(fog_box(phase), phase_k=0.2, **SMALL).phase_k == 0.2


def test_the_phase_changes_the_image_as_the_scene_says():
    """Forward scattering (hg g = 0.6) seen from the side, across the beam: darker than isotropic
    fog; the same image as an explicit phase_k of the mapped value."""
    iso = mean(VolumePipeline(fog_box(None), **SMALL).render())
    hg = VolumePipeline(fog_box({"type": "hg", "g": 0.6}), **SMALL)
    forward = hg.render()
    assert mean(forward) < 0.8 * iso
    explicit = VolumePipeline(fog_box(None), phase_k=hg.phase_k, **SMALL).render()
    assert mean(explicit) == pytest.approx(mean(forward), rel=1e-6)


def test_another_phase_function_asks_for_phase_k():
    scene = fog_box({"type": "rayleigh"})
    with pytest.raises(SceneError, match="set phase_k"):
        VolumePipeline(scene, **SMALL).render()
    assert VolumePipeline(scene, phase_k=0.1, **SMALL).phase_k == 0.1


def test_builtins_keep_suns_k_and_phase_k_is_a_float_parameter():
    assert VolumePipeline("glass_sphere_fog", width=8, height=6, **SMALL).phase_k == 0.3
    assert field_types(VolumeParams)["phase_k"] is float
    assert VolumeParams().phase_k is None
