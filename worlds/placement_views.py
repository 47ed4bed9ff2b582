"""Registration views of the simulated world, rendered and exposed as the simulated camera forms its frames
(Mitsuba, then the sensor model): what ``hlr_lab.placement`` measures a placement from, with the truth
known. The benchmark and the tests call it; the rig's own capture goes through the camera driver."""

from __future__ import annotations

import numpy as np

from hlr_lab.geometry.camera import Camera
from hlr_lab.placement.photographs import Sensor, ViewFrames
from sim.render.camera import CameraSpec
from sim.render.renderer import Renderer
from sim.render.scene import SceneSpec
from sim.render.sensor import SensorModel

BRACKET = (1.0, 1 / 8)  # exposures relative to the one that puts the view's 99.5th percentile at 3000 DN


def photograph_views(
    scene: SceneSpec,
    camera: Camera,
    turntable_deg: list[float],
    lamps: np.ndarray,
    *,
    sensor: SensorModel | None = None,
    spp: int = 16,
    seed: int = 0,
) -> tuple[list[ViewFrames], Sensor]:
    """Per turntable angle, the frames (L, 2, H, W, 3) DN under each of ``lamps`` (L, 3) (world, m), two
    exposures apart by 8×; and what the frames need to be read (the sensor's black level, read noise, top).
    """
    sensor = sensor or SensorModel()
    spec = CameraSpec(camera.matrix, camera.distortion, camera.rotation, camera.translation, camera.width,
                      camera.height)  # fmt: skip
    renderer = Renderer(scene, spec, spp=spp)
    rng = np.random.default_rng(seed)
    views = []
    for angle in turntable_deg:
        images = [renderer.render(float(angle), lamp, seed=seed) for lamp in lamps]
        bright = max(float(np.percentile(image[image > 0], 99.5)) for image in images if (image > 0).any())
        exposures = np.array(BRACKET) * 3000 / (sensor.sensitivity * bright)
        frames = np.stack(
            [np.stack([sensor.expose(image, float(t), rng) for t in exposures]) for image in images]
        )
        views.append(ViewFrames(float(angle), frames, exposures))
    return views, Sensor(sensor.black_level_dn, sensor.read_noise_dn, float(sensor.top))
