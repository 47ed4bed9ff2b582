"""Radiometric calibration: the solver against frames drawn from a known sensor (seeded, no renderer),
the simulated sensor and lamp read from a true rig file, and ``calibrate radiometric`` on the simulated
bench whose sensor and lamp are off their nominal values (builtin:bench-night, its lamp held steady)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from calibration.charuco import CalibrationError
from calibration.radiometry import dark_statistics, lamp_sensitivity, photon_transfer
from sim.lamp import LampModel
from sim.render.sensor import SensorModel
from sim.true_rig import load_true_rig

TRUE = SensorModel(
    bits=12, sensitivity=3600.0, electrons_per_dn=1 / 0.31, read_noise_dn=2.2, black_level_dn=64.0
)
POWER = 0.88  # S · Φ = 3168
SHAPE = (60, 80, 3)
NIGHT_RADIOMETRY = """[light]
type = "point"
power = 0.88

[sensor]
sensitivity = 3600.0
black_level_dn = 64.0
read_noise_dn = 2.2
conversion_gain_dn_per_e = 0.31

"""  # builtin:bench-night's, without its drift


def _illumination(rng) -> np.ndarray:
    """A smooth, uneven light on the reference (a real lamp is never flat), (H, W, 3) radiance units."""
    y, x = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]]
    light = 1.0 + 0.2 * np.sin(x / 17.0) * np.cos(y / 23.0)
    return np.repeat(light[..., None], 3, axis=2)


def test_the_sensor_and_the_lamp_are_recovered_from_frames_of_a_known_sensor():
    """Black level within 0.5 DN, read noise within 5 %, conversion gain within 3 %, S·Φ within 1 % (the
    issue's targets; measured 0.02 DN, 0.6 %, 0.4 %, 0.05 %), the response linear, the lamp following
    1/d². 12-bit frames of 60×80 pixels: the tolerances are the targets, several standard errors wide."""
    rng = np.random.default_rng(7)
    darks = [
        (TRUE.expose(np.zeros(SHAPE), t, rng), TRUE.expose(np.zeros(SHAPE), t, rng)) for t in (0.02, 0.005)
    ]
    dark = dark_statistics(darks)
    assert np.abs(dark.black_level_dn - 64.0).max() < 0.5
    assert dark.read_noise_dn == pytest.approx(2.2, rel=0.05)

    light = _illumination(rng)
    exposures = 0.9 * np.geomspace(0.05, 1.0, 8)  # up to ~3000 DN of 4095
    pairs = [
        (TRUE.expose(light, t, rng).reshape(-1, 3), TRUE.expose(light, t, rng).reshape(-1, 3))
        for t in exposures
    ]
    reference = [TRUE.expose(light, 0.3, rng).mean() for _ in exposures]
    transfer = photon_transfer(pairs, exposures, np.array(reference), dark, TRUE.top)
    assert transfer.conversion_gain_dn_per_e == pytest.approx(0.31, rel=0.03)
    assert transfer.worst_nonlinearity < 0.005

    reflectance = np.array([0.99, 0.6, 0.3])  # per channel: the solve keeps them apart
    factors, values, times = [], [], []
    for d in (0.25, 0.3, 0.35, 0.4):  # the lamp straight above at four distances; cos θ = 1 over the patch
        geo = np.full(SHAPE[0] * SHAPE[1], 1 / d**2)
        radiance = (POWER * geo[:, None] * reflectance[None, :]).reshape(SHAPE)
        t = 0.5 * TRUE.top / (TRUE.sensitivity * radiance.max())
        values.append(TRUE.expose(radiance, t, rng).reshape(-1, 3))
        factors.append(geo)
        times.append(t)
    lamp = lamp_sensitivity(values, np.array(times), np.zeros(4), factors, reflectance, dark)
    np.testing.assert_allclose(lamp.sensitivity_times_power, 3600 * POWER, rtol=0.01)
    assert lamp.follows_inverse_square


@pytest.mark.parametrize("black", [0.0, 0.5, 64.0])
def test_a_black_level_at_zero_is_measured_through_the_clipping(black):
    """The simulated sensor's dark frames (read noise 1.5 DN, clipped at 0 DN as builtin:bench-offsets'
    camera does with its black level at 0): black level within 0.03 DN and read noise within 2 % of the
    truth (3 pairs of 60 × 80 × 3 pixels: standard errors ~0.005 DN and 0.4 %). The plain mean and spread
    were 0.59 DN high and 40 % low at a black level of 0, and the fit of every dark region with them."""
    sensor = SensorModel(bits=12, sensitivity=4095.0, electrons_per_dn=1 / 0.31, read_noise_dn=1.5,
                         black_level_dn=black)  # fmt: skip
    rng = np.random.default_rng(5)
    dark = np.zeros(SHAPE)
    pairs = [(sensor.expose(dark, t, rng), sensor.expose(dark, t, rng)) for t in (0.01, 0.04, 0.16)]
    found = dark_statistics(pairs)
    np.testing.assert_allclose(found.black_level_dn, black, atol=0.03)
    assert found.read_noise_dn == pytest.approx(1.5, rel=0.02)
    assert found.black_level_se_dn < 0.03


def test_a_black_level_at_zero_is_never_measured_below_zero():
    """With the true black level at 0 the free fit came out below it half the time (−0.02 DN on the
    simulated rig at 640 × 480), and the calibrated rig file was refused (a black level is ≥ 0): over 20
    seeds every channel's level is ≥ 0 and within 0.1 DN of the truth (one pair of 60 × 80 pixels: a
    standard error of ~0.02 DN, and the largest of 60 levels ~3 of them), the read noise within 3 %."""
    sensor = SensorModel(bits=12, sensitivity=4095.0, electrons_per_dn=1 / 0.31, read_noise_dn=1.5,
                         black_level_dn=0.0)  # fmt: skip
    levels = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        found = dark_statistics(
            [(sensor.expose(np.zeros(SHAPE), 0.01, rng), sensor.expose(np.zeros(SHAPE), 0.01, rng))]
        )
        levels.append(found.black_level_dn)
        assert found.read_noise_dn == pytest.approx(1.5, rel=0.03)
    levels = np.array(levels)  # (20, 3)
    assert levels.min() >= 0.0
    assert levels.max() < 0.1
    assert (levels == 0.0).any()  # the bound did act: some fits wanted a level below 0


def test_a_response_that_is_not_linear_is_refused():
    gamma = SensorModel(
        bits=12, sensitivity=3600.0, electrons_per_dn=4.0, read_noise_dn=2.2, response="gamma"
    )
    rng = np.random.default_rng(3)
    dark = dark_statistics(
        [(gamma.expose(np.zeros(SHAPE), 0.01, rng), gamma.expose(np.zeros(SHAPE), 0.01, rng))]
    )
    light = _illumination(rng)
    exposures = 0.9 * np.geomspace(0.05, 1.0, 6)
    pairs = [
        (gamma.expose(light, t, rng).reshape(-1, 3), gamma.expose(light, t, rng).reshape(-1, 3))
        for t in exposures
    ]
    reference = [gamma.expose(light, 0.3, rng).mean() for _ in exposures]
    with pytest.raises(CalibrationError, match=r"from linear.*raw, linear output"):
        photon_transfer(pairs, exposures, np.array(reference), dark, gamma.top)


def test_a_lamp_that_does_not_fall_off_as_the_inverse_square_is_flagged():
    """A lamp twice as far gives a quarter of the light; one that gives a third (a diffuse source seen from
    near) is flagged."""
    rng = np.random.default_rng(5)
    dark = dark_statistics(
        [(TRUE.expose(np.zeros(SHAPE), 0.01, rng), TRUE.expose(np.zeros(SHAPE), 0.01, rng))]
    )
    values, factors = [], []
    for d in (0.2, 0.4):
        geo = np.full(SHAPE[0] * SHAPE[1], 1 / d**2)
        real = 1 / d ** (1.6)  # falls off slower than 1/d²
        values.append(TRUE.expose(np.full(SHAPE, 0.5 * real), 0.1, rng).reshape(-1, 3))
        factors.append(geo)
    lamp = lamp_sensitivity(values, np.array([0.1, 0.1]), np.zeros(2), factors, np.full(3, 0.99), dark)
    assert not lamp.follows_inverse_square
    assert lamp.inverse_square_residual > 0.1


def test_the_true_rig_gives_the_world_its_sensor_and_lamp():
    night = load_true_rig("builtin:bench-night")
    assert (night.sensor.sensitivity, night.sensor.black_level_dn, night.sensor.read_noise_dn) == (
        3600.0,
        64.0,
        2.2,
    )
    assert night.sensor.electrons_per_dn == pytest.approx(1 / 0.31)
    assert night.lamp.power == 0.88
    lamp = night.lamp
    # cold, 4 % short of its power, made up with a 400 s time constant; then −1 % per hour
    assert lamp.output(0.0) == pytest.approx(0.88 * 0.96)
    assert lamp.output(1200.0) == pytest.approx(0.88 * (1 - 0.04 * np.exp(-3) - 0.01 / 3))
    flicker = [lamp.output(3600.0, np.random.default_rng(i)) for i in range(200)]
    assert np.std(flicker) / np.mean(flicker) == pytest.approx(0.001, rel=0.3)
    steady = load_true_rig("builtin:bench-offsets")
    assert steady.lamp == LampModel()
    assert steady.sensor == SensorModel()  # the drawing's sensor: what the world rendered with before


def test_the_black_level_is_added_after_the_noise_and_clipped_at_the_top():
    sensor = SensorModel(
        bits=10, sensitivity=1000.0, electrons_per_dn=None, read_noise_dn=0.0, black_level_dn=40.0
    )
    assert sensor.expose(np.zeros((2, 2, 3)), 1.0, np.random.default_rng(0)).max() == 40
    assert sensor.expose(np.full((2, 2, 3), 0.1), 1.0, np.random.default_rng(0)).min() == 140
    assert sensor.expose(np.full((2, 2, 3), 5.0), 1.0, np.random.default_rng(0)).min() == 1023


@pytest.mark.slow
def test_calibrate_radiometric_on_the_simulated_bench(tmp_path, capsys):
    """A world built as the drawing but with builtin:bench-night's sensor and lamp power (its lamp held
    steady: the drift is another test's; its geometry right: a geometry off its drawing moves every d²,
    which is the geometric calibration's business — 2.2 % of S·Φ on bench-night's offsets). hlr-lab
    believes the drawing's sensor (4095, black 0, read noise 1.5); the calibrated file says the world's
    within the issue's targets (measured: black 0.00 DN, read noise +0.8 %, gain −0.1 %, S·Φ −0.07 %)."""
    from tests.renderer_guard import require_renderer

    require_renderer()
    from hlr_lab.cli.main import main
    from hlr_lab.rig.file import load_rig

    drawing = (Path(__file__).resolve().parents[1] / "hlr_lab" / "data" / "sim-rig.toml").read_text()
    steady = tmp_path / "steady.toml"
    steady.write_text(re.sub(r"(?ms)^\[light\].*?(?=^\[calibration\.board\])", NIGHT_RADIOMETRY, drawing))
    command = ["calibrate", "radiometric", "--sim", "--true-rig", str(steady), "--out", str(tmp_path / "images"),
               "-o", str(tmp_path / "calibrated.toml"), "--speed-factor", "40"]  # fmt: skip
    assert main(command) == 0, capsys.readouterr().err
    sensor = load_rig(tmp_path / "calibrated.toml").file.sensor
    assert abs(sensor.black_level_dn - 64.0) < 0.5
    assert sensor.read_noise_dn == pytest.approx(2.2, rel=0.05)
    assert sensor.conversion_gain_dn_per_e == pytest.approx(0.31, rel=0.03)
    assert sensor.sensitivity == pytest.approx(3600 * 0.88, rel=0.01)  # the file's power is 1
    record = load_rig(tmp_path / "calibrated.toml").file.calibration.radiometric
    assert record.follows_inverse_square
    assert record.worst_nonlinearity < 0.01
    # solved again from the photographs, without the rig: the same numbers
    again = [
        "calibrate",
        "radiometric",
        "--sim",
        "--from",
        str(tmp_path / "images"),
        "-o",
        str(tmp_path / "again.toml"),
    ]
    assert main(again) == 0
    assert load_rig(tmp_path / "again.toml").file.sensor == sensor


def test_a_rig_file_without_a_white_reference_or_with_it_out_of_view_is_refused(tmp_path, capsys):
    from hlr_lab.cli.main import main

    text = (Path(__file__).resolve().parents[1] / "hlr_lab" / "data" / "sim-rig.toml").read_text()
    bare = tmp_path / "bare.toml"
    bare.write_text(text[: text.index("[calibration.white_reference]")])
    assert (
        main(["calibrate", "radiometric", "--rig", str(bare), "--sim", "-o", str(tmp_path / "x.toml")]) == 1
    )
    assert "no [calibration.white_reference]" in capsys.readouterr().err
    away = tmp_path / "away.toml"
    away.write_text(
        text.replace("place_m = [0.0, 0.0]             # its centre", "place_m = [0.3, 0.3]  # its centre")
    )
    command = ["calibrate", "radiometric", "--rig", str(away), "--sim", "--out", str(tmp_path / "i"), "-o",
               str(tmp_path / "y.toml")]  # fmt: skip
    assert main(command) == 1
    assert "not wholly in view" in capsys.readouterr().err
    assert not (tmp_path / "y.toml").exists()


def _frames(rig, white_level: int, dark_level: int = 64) -> list:
    """A capture's frames drawn by hand: dark pairs, three photon-transfer levels, three white frames at
    ``white_level`` DN over the whole image (the reference's middle included)."""
    from calibration.radiometric_procedure import RadiometricFrame

    rng = np.random.default_rng(0)
    shape = (rig.camera.height, rig.camera.width, 3)

    def frame(level: float) -> np.ndarray:
        noisy = level + rng.normal(0, np.sqrt(2.2**2 + 0.31 * max(level - 64, 0)), shape)
        return np.clip(np.round(noisy), 0, 4095).astype(np.uint16)

    ticks = rig.gantry.kinematics.ticks_for(-90.0, 75.0)
    frames = [RadiometricFrame(frame(dark_level), "dark", 0, 0.02, 0.0, ticks, 12, 0.0) for _ in range(2)]
    for level, t in enumerate((0.002, 0.005, 0.01)):
        frames.append(RadiometricFrame(frame(64 + 1000), "reference", level, 0.006, 0.0, ticks, 12, 0.0))
        frames += [
            RadiometricFrame(frame(64 + 1000 * t / 0.006), "flat", level, t, 0.0, ticks, 12, 0.0)
            for _ in range(2)
        ]
    frames += [RadiometricFrame(frame(white_level), "white", i, 0.01, 0.0, ticks, 12, 0.0) for i in range(3)]
    return frames


def test_a_saturated_reference_or_a_lamp_that_did_not_light_it_is_refused(rig):
    from calibration.radiometric_procedure import solve_radiometric

    with pytest.raises(CalibrationError, match="saturated"):
        solve_radiometric(_frames(rig, white_level=4095), rig)
    with pytest.raises(CalibrationError, match="as dark as the dark frames"):
        solve_radiometric(_frames(rig, white_level=70), rig)
    solve_radiometric(_frames(rig, white_level=2000), rig)  # the same frames, lit and unclipped: solved


def test_a_calibration_whose_result_a_rig_file_refuses_writes_nothing_and_names_the_output(tmp_path):
    """A result hlr-lab would refuse (here a black level below 0) is one line naming the file asked for
    and the field — not the scratch copy it was checked in — and nothing is written or left behind."""
    from hlr_lab.errors import InputError
    from hlr_lab.rig.calibrated import write_calibrated_rig
    from tests.films import DRAWING

    output = tmp_path / "rig-radiometric.toml"
    with pytest.raises(InputError) as refused:
        write_calibrated_rig(
            DRAWING, output, {"sensor": {"black_level_dn": -0.02}}, "radiometric", {"frames": 3}
        )
    said = str(refused.value)
    assert said.startswith(f"{output}: sensor.black_level_dn: the radiometric calibration's result")
    assert "greater than or equal to 0" in said
    assert "check.toml" not in said
    assert list(tmp_path.iterdir()) == []
