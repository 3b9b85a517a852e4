"""Every pipeline that renders from the scene's sensor refuses a scene without one, by name
(``scenes.load_with_sensor``), before any work."""

import pytest

from photonmap import ParameterError, ScreenPipeline, SPPMPipeline, SurfacePipeline


@pytest.mark.parametrize("pipeline", [SurfacePipeline, SPPMPipeline, ScreenPipeline])
def test_a_scene_without_a_sensor_is_refused(pipeline):
    with pytest.raises(ParameterError, match="no sensor"):
        pipeline({"type": "scene", "ball": {"type": "sphere"}})


def test_method_parameters_reach_the_method_and_scene_parameters_the_scene():
    pipe = SurfacePipeline("cornell_steinhurst", width=16, height=12, photons=1000)
    assert pipe.params.photons == 1000
    assert tuple(pipe.sensor.film().size()) == (16, 12)
