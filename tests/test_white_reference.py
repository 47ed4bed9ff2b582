"""The lamp measured on a white reference beside the object (hlr_lab.acquisition.white_reference): which of its points
count in a pose (seen, lit, not grazing: never one the object hides or shadows, checked against a
brute-force ray test on a box), and the brightness recovered from synthetic frames of a known sensor."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from drivers.protocols import RawFrame
from hlr_lab.acquisition.white_reference import MIN_COS, SHADOW_MARGIN_M, RunReference, brightness
from hlr_lab.geometry.silhouette import object_window
from hlr_lab.geometry.sphere import rotation_z
from hlr_lab.rig.file import sim_rig

BOX = (np.array([-0.04, -0.04, 0.0]), np.array([0.04, 0.04, 0.10]))  # the object: 8 × 8 × 10 cm on the plate


def box_vertices() -> np.ndarray:
    lo, hi = BOX
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def segment_hits_box(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) bool: the segments from a (N, 3) to b (N, 3) pass through the box (slab test)."""
    lo, hi = BOX
    d = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - a) / d, (hi - a) / d
    near = np.nanmax(np.where(np.isfinite(np.minimum(t1, t2)), np.minimum(t1, t2), -np.inf), axis=1)
    far = np.nanmin(np.where(np.isfinite(np.maximum(t1, t2)), np.maximum(t1, t2), np.inf), axis=1)
    return (near <= far) & (far > 1e-9) & (near < 1 - 1e-9)


def reference(place=(0.08, 0.0)) -> RunReference:
    camera = sim_rig().camera
    return RunReference(camera, box_vertices(), window=box_window(camera), place_m=place, size_m=0.05,
                        height_m=0.0, reflectance=np.array([0.99, 0.98, 0.97]))  # fmt: skip


def box_window(camera):
    return lambda turntable_deg: object_window(camera, box_vertices(), turntable_deg)


@pytest.mark.parametrize("turntable_deg", [0.0, 60.0, 120.0, 180.0, -60.0, -120.0])
@pytest.mark.parametrize("lamp", [(0.25, -0.05, 0.25), (-0.1, 0.2, 0.3), (0.05, -0.25, 0.15)])
def test_no_point_the_object_hides_or_shadows_is_measured(turntable_deg, lamp):
    """Every pixel kept sees, at its centre, a point of the reference's middle that nothing of the box
    stands between and the lamp or the camera (rays checked one by one), lit at cos θ ≥ MIN_COS, with
    that point's own cos θ / d²."""
    ref, camera = reference(), sim_rig().camera
    lamp = np.array(lamp)
    sight = ref.sight(turntable_deg, lamp)
    assert sight is not None
    turn = rotation_z(np.radians(turntable_deg))
    lamp_tt = turn[:3, :3].T @ lamp
    seen_from = camera.in_frame(turn)
    points = sight.points
    uv, _ = seen_from.project(points)  # each point is where its pixel's centre looks
    np.testing.assert_allclose(uv, sight.rows_cols[:, ::-1], atol=1e-6)
    assert np.all((points[:, :2] >= ref.low) & (points[:, :2] <= ref.high))
    assert not segment_hits_box(points, np.tile(lamp_tt, (len(points), 1))).any()
    assert not segment_hits_box(points, np.tile(seen_from.centre, (len(points), 1))).any()
    to_lamp = lamp_tt - points
    d2 = np.einsum("ij,ij->i", to_lamp, to_lamp)
    cos = to_lamp[:, 2] / np.sqrt(d2)
    assert (cos >= MIN_COS).all()
    np.testing.assert_allclose(sight.irradiance, cos / d2)


def test_a_partly_shadowed_reference_keeps_its_lit_part():
    """With the lamp high above, every pixel of the reference's middle is kept; with it low behind the box,
    the box's shadow (by the brute-force test) covers part of them: the rest are kept, but for a band
    SHADOW_MARGIN_M wide along the shadow's edge (the convex hull of a box's shadow is its shadow)."""
    ref = reference()
    everything = ref.sight(-120.0, np.array([0.0, 0.0, 2.0]))
    lamp = np.array([-0.1, 0.2, 0.3])
    lamp_tt = rotation_z(np.radians(-120.0))[:3, :3].T @ lamp
    shadowed = segment_hits_box(everything.points, np.tile(lamp_tt, (len(everything.points), 1)))
    assert 0.2 < shadowed.mean() < 0.8
    sight = ref.sight(-120.0, lamp)
    lit = {tuple(p) for p in everything.rows_cols[~shadowed]}
    kept = {tuple(p) for p in sight.rows_cols}
    assert kept <= lit
    # kept: every lit pixel whose point lies farther than the margin (and a pixel's footprint) from the shadow
    to_shadow = cKDTree(everything.points[shadowed, :2]).query(everything.points[~shadowed, :2])[0]
    far = to_shadow > SHADOW_MARGIN_M + 5e-4
    assert {tuple(p) for p in everything.rows_cols[~shadowed][far]} <= kept
    assert far.sum() > 0.5 * len(lit)


def test_a_lamp_no_higher_than_the_object_measures_nothing():
    assert reference().sight(0.0, np.array([0.3, 0.0, 0.09])) is None


def test_the_reference_behind_the_object_is_not_seen():
    """Turned to the far side (behind the box from the camera on −y), none of it is measured."""
    sight = reference(place=(0.0, 0.07)).sight(0.0, np.array([0.0, 0.1, 0.3]))
    assert sight is not None
    assert len(sight.irradiance) == 0


def test_brightness_is_recovered_from_frames_of_a_known_sensor():
    """Synthetic 12-bit frames: DN = black + k · g · t · R · cos θ / d² + read noise (σ 1.5 DN, seeded) at the
    points in sight; a bracket whose long frame clips and whose short one is dark. The brightness comes
    from the middle frame, within 0.1 % (the noise averages over ~1 000 values of ~1 500 DN: ~0.002 %;
    rounding to whole DN: less)."""
    rng = np.random.default_rng(7)
    ref = reference()
    sight = ref.sight(-30.0, np.array([0.2, -0.1, 0.28]))
    k, black, h, w = 2.0e5, 64.0, 960, 1280
    assert len(sight.irradiance) > 100
    frames = []
    middle = 1500 / (k * np.median(sight.irradiance))  # ~1 500 DN: a third of full scale
    for t, at in ((10 * middle, 1.0), (middle, 2.0), (middle / 10, 3.0)):
        pixels = np.full((h, w, 3), black)
        signal = k * t * sight.irradiance[:, None] * ref.reflectance[None, :]
        pixels[sight.rows_cols[:, 0], sight.rows_cols[:, 1]] += signal
        pixels = np.clip(np.round(pixels + rng.normal(0, 1.5, pixels.shape)), 0, 4095).astype(np.uint16)
        frames.append(RawFrame(pixels, 12, t, 0.0, at))
    reading = brightness(frames, sight, ref.reflectance, black)
    assert reading is not None
    assert reading.at == 2.0  # the middle frame: well exposed
    assert reading.brightness == pytest.approx(k, rel=1e-3)
    gained = [RawFrame(f.pixels, 12, f.exposure_s / 2, 20 * np.log10(2), f.captured_at) for f in frames]
    assert brightness(gained, sight, ref.reflectance, black).brightness == pytest.approx(k, rel=1e-3)
    dark = [RawFrame(np.full((h, w, 3), 64, np.uint16), 12, 0.04, 0.0, 1.0)]
    assert brightness(dark, sight, ref.reflectance, black) is None


def test_a_directional_light_with_a_run_reference_is_refused_naming_the_field(tmp_path):
    """The reference's brightness is modelled for a point lamp (1/d²): a rig with a directional light and
    run_place_m is one clear error."""
    from hlr_lab.acquisition.white_reference import reference_meter
    from hlr_lab.errors import InputError
    from hlr_lab.rig.file import load_rig

    drawing = (Path(__file__).resolve().parents[1] / "hlr_lab" / "data" / "sim-rig.toml").read_text()
    text = drawing.replace('type = "point"', 'type = "directional"').replace(
        "place_m = [0.0, 0.0]             #", "run_place_m = [0.1, 0.0]\nplace_m = [0.0, 0.0]  #"
    )
    (tmp_path / "rig.toml").write_text(text)
    rig = load_rig(tmp_path / "rig.toml")
    assert rig.file.calibration.white_reference.run_place_m == [0.1, 0.0]
    with pytest.raises(InputError, match="point lamp") as refused:
        reference_meter(rig, box_vertices(), box_window(rig.camera))
    assert refused.value.field == "calibration.white_reference.run_place_m"
    plain = sim_rig()  # no run reference: the reference pose's way
    assert reference_meter(plain, box_vertices(), box_window(plain.camera)) is None
