"""An OpenCV camera (K, distortion k1 k2 p1 p2 k3) as a Mitsuba sensor: each sample's ray leaves the
camera's centre through the point of the camera's own pixel grid the sampler chose, undistorted in Dr.Jit.

The film is the camera's image, so its box filter is the camera pixel's own box: nothing is resampled.
(Rendering an undistorted film and remapping it bilinearly onto the camera's pixels, as the simulator
once did, blurred every pixel by the remap's tent on top of its box — twice the box's variance — which a
real sensor does not do; docs/fitting.md, "The pixel's footprint".)
"""

# Mitsuba's stubs describe its C++ classes; a Python plugin written after its documented pattern looks
# wrong to them
# pyright: reportAttributeAccessIssue=false, reportIncompatibleMethodOverride=false, reportOperatorIssue=false

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from sim.render.camera import COEFFICIENTS, SENSOR_PLUGIN

# fixed-point undistortion, as cv2.undistortPoints does; measured at the corners of the built-in rigs'
# cameras (k1 ≈ −0.045): reprojected within 3e-6 px after 3 iterations, 3e-8 after 4, 1e-12 after 6;
# 20 leave a margin for a lens with stronger distortion (float32 rays stop at ~1e-4 px anyway)
ITERATIONS = 20


class OpenCVCamera(mi.Sensor):
    """Properties: ``fx fy cx cy`` (pixels, OpenCV: pixel centres at integers, x right, y down),
    ``k1 k2 p1 p2 k3``, ``to_world`` (camera → world: columns x right, y down, z forward, and the
    centre), and a film the camera's size."""

    def __init__(self, props):
        mi.Sensor.__init__(self, props)
        self.intrinsics = tuple(float(props[k]) for k in ("fx", "fy", "cx", "cy"))
        self.coefficients = tuple(float(props.get(k, 0.0)) for k in COEFFICIENTS)

    def sample_ray(self, time, wavelength_sample, position_sample, aperture_sample, active=True):
        film = self.film()
        offset, size = film.crop_offset(), film.crop_size()
        # position_sample spans the crop window; Mitsuba's pixel (i, j) covers [i, i+1): OpenCV's centre i
        u = offset[0] + position_sample.x * size[0] - 0.5
        v = offset[1] + position_sample.y * size[1] - 0.5
        fx, fy, cx, cy = self.intrinsics
        k1, k2, p1, p2, k3 = self.coefficients
        xd, yd = (u - cx) / fx, (v - cy) / fy
        x, y = mi.Float(xd), mi.Float(yd)
        for _ in range(ITERATIONS):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            x, y = (xd - dx) / radial, (yd - dy) / radial
        to_world = self.world_transform()
        direction = dr.normalize(to_world @ mi.Vector3f(x, y, 1.0))
        # time and wavelengths keep their defaults: nothing moves during an exposure, the variant is RGB
        return mi.Ray3f(mi.Point3f(to_world.translation()), direction), mi.Color3f(1.0)

    def sample_ray_differential(self, time, wavelength_sample, position_sample, aperture_sample, active=True):
        ray, weight = self.sample_ray(time, wavelength_sample, position_sample, aperture_sample, active)
        return mi.RayDifferential3f(ray), weight


_registered = False


def register() -> None:
    global _registered
    if not _registered:
        mi.register_sensor(SENSOR_PLUGIN, lambda props: OpenCVCamera(props))
        _registered = True
