"""The object window: every pixel the object covers (by an independent per-pixel ray cast) is inside
it, and it leaves most of the frame out."""

import numpy as np
import pytest

from hlr_lab.geometry.silhouette import object_window
from hlr_lab.geometry.sphere import rotation_z
from hlr_lab.object.raycast import RayCaster
from hlr_lab.planning.geometry import placement
from tests.cameras import half_size_camera


@pytest.mark.parametrize("turntable_deg", [0.0, 90.0, 215.0])
def test_the_window_holds_every_object_pixel(pebble_object, turntable_deg):
    mesh = pebble_object.mesh
    on_table = mesh.transformed(placement(mesh))
    camera = half_size_camera()
    window = object_window(camera, on_table.vertices, turntable_deg, margin_px=0)
    hits = RayCaster(on_table).gbuffer(camera.in_frame(rotation_z(np.radians(turntable_deg)))).face >= 0
    assert hits.sum() > 1000
    assert not (hits & ~window).any()  # conservative: the hull of the projected vertices holds the silhouette
    assert window.sum() < 1.3 * hits.sum()  # and tight for a convex-ish object
    grown = object_window(camera, on_table.vertices, turntable_deg, margin_px=8)
    assert grown.sum() > window.sum()
    assert not (window & ~grown).any()


def test_an_object_behind_the_camera_has_an_empty_window(pebble_object):
    camera = half_size_camera()
    behind = camera.centre - 0.5 * camera.forward
    assert not object_window(camera, pebble_object.mesh.vertices * 0.01 + behind, 0.0).any()
