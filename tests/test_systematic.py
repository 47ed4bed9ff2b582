"""The systematic uncertainty's parts that need no photographs: the robust fit's linearisation against
refits, and the rig's uncertainty read from its calibration records as independent terms."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hlr_lab.fitting import fit_region, fit_shift
from hlr_lab.fitting.synthetic import Truth, synthetic_region
from hlr_lab.reflectance.systematic import UNCALIBRATED, camera_terms, gantry_terms, rig_terms
from hlr_lab.rig.file import CAMERA_PARAMETERS, GANTRY_PARAMETERS, load_rig, sim_rig

SIM_RIG = Path(__file__).resolve().parents[1] / "hlr_lab" / "data" / "sim-rig.toml"
OBJECT = np.random.default_rng(1).normal(0.0, 0.02, (500, 3)) + np.array(
    [0.0, 0.0, 0.03]
)  # a 2 cm blob on the plate


def rig_with_records(tmp_path: Path, camera: np.ndarray, gantry: np.ndarray, sensor: tuple[float, float]):
    """builtin:sim's rig file with calibration records carrying these covariances (14 × 14, 8 × 8) and
    the radiometric standard errors (relative sensitivity, black level DN)."""

    def table(m: np.ndarray) -> str:
        return "[" + ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in m) + "]"

    text = (
        SIM_RIG.read_text()
        + f"""
[calibration.camera]
date = "2026-12-03T10:00:00+0000"
hlr_lab = "test"
covariance_of = {list(CAMERA_PARAMETERS)!r}
covariance = {table(camera)}

[calibration.gantry]
date = "2026-12-03T10:00:00+0000"
hlr_lab = "test"
covariance_of = {list(GANTRY_PARAMETERS)!r}
covariance = {table(gantry)}

[calibration.radiometric]
date = "2026-12-03T10:00:00+0000"
hlr_lab = "test"
sensitivity_se_rel = {sensor[0]!r}
black_level_se_dn = {sensor[1]!r}
""".replace("'", '"')
    )
    path = tmp_path / "rig-with-records.toml"
    path.write_text(text)
    return load_rig(path)


@pytest.mark.parametrize("move", ["cos_beta", "irradiance", "intensity"])
def test_the_linearised_fit_moves_as_a_refit_does(move):
    """The robust fit's response to inputs moved by a little (β 10⁻⁵ wider, L·cos α 10⁻⁵ more, the pixels
    10⁻⁵ darker) is the difference of two full fits, to 2 % of the move and 0.005 standard errors (seeded
    sphere, 60 000 pixels; measured: three digits alike)."""
    r = synthetic_region(Truth(np.array([0.5, 0.3, 0.2]), np.full(3, 0.2), 60.0), shape="sphere", light="point",
                         pixels=60_000, bits=12, seed=3)  # fmt: skip
    fit = fit_region(r.intensity, r.irradiance, r.cos_alpha, r.cos_beta, theta_c_deg=20.0)
    inputs = {
        "intensity": r.intensity,
        "irradiance": r.irradiance,
        "cos_alpha": r.cos_alpha,
        "cos_beta": r.cos_beta,
    }
    if move == "cos_beta":
        inputs["cos_beta"] = np.cos(np.arccos(r.cos_beta) * (1 + 1e-5))
    elif move == "irradiance":
        inputs["irradiance"] = r.irradiance * (1 + 1e-5 * r.cos_alpha)
    else:
        inputs["intensity"] = r.intensity / (1 + 1e-5)
    predicted = fit_shift(fit, **inputs)
    again = fit_region(**inputs, theta_c_deg=20.0)
    refit = np.concatenate([again.rd - fit.rd, again.rs - fit.rs, [again.n - fit.n]])
    se = np.concatenate([fit.rd_se, fit.rs_se, [fit.n_se]])
    assert np.max(np.abs(refit)) > 0
    np.testing.assert_array_less(np.abs(predicted - refit), 0.02 * np.abs(refit) + 0.005 * se)


def test_a_rig_never_calibrated_gets_the_stated_fractions_and_says_so():
    """builtin:sim has no calibration record: its camera and gantry are one term each, the stated share of
    every value (a drawing is pixels and millimetres off, beyond any first-order move); the sensor's two
    quantities move by their defaults; every term's source is "uncalibrated"."""
    terms = rig_terms(sim_rig(), OBJECT)
    assert [t.name for t in terms] == ["camera (not calibrated)", "gantry (not calibrated)", "sensitivity × power",
                                       "black level"]  # fmt: skip
    assert {t.source for t in terms} == {"uncalibrated"}
    assert terms[0].fraction == UNCALIBRATED["camera"]
    assert terms[1].fraction == UNCALIBRATED["gantry"]
    assert terms[2].sensitivity_factor == pytest.approx(1.10)
    assert terms[3].black_level_dn == pytest.approx(sim_rig().file.sensor.black_level_dn + 2.0)


def test_the_cameras_modes_follow_its_covariance_not_its_standard_errors(tmp_path):
    """In a turntable calibration the principal point and the camera's pose trade off: cx 0.5 px right
    with the camera 0.5·d/f to the other side (d its distance) shows the object where it was. A
    covariance that says so (the two perfectly correlated) moves the object's image by a few hundredths
    of what the same standard errors taken alone do (0.5 px each); a covariance of the two uncorrelated
    moves it by their 0.5 px each. Gantry: each mode moves the lamp; the sensor's terms are the record's."""
    camera = sim_rig().camera
    along = np.zeros(14)
    along[CAMERA_PARAMETERS.index("cx_px")] = 0.5
    along[CAMERA_PARAMETERS.index("translation_x_m")] = -0.5 * camera.translation[2] / camera.matrix[0, 0]
    correlated = np.outer(along, along)
    alone = np.diag(np.square(along))
    gantry = np.diag([1e-8] * 6 + [1.0, 1.0])  # centre, arm, axis 0.1 mm / 1e-4; zero ticks 1
    rig = rig_with_records(tmp_path, correlated, gantry, (0.002, 0.05))
    tied = camera_terms(rig, OBJECT)
    assert [t.source for t in tied] == ["covariance"]
    moved = tied[0].camera
    assert moved is not None
    seen = moved.project(OBJECT)[0] - rig.camera.project(OBJECT)[0]
    assert np.sqrt(np.mean(np.sum(seen**2, axis=1))) < 0.03  # the parallax of a 2 cm object
    free = camera_terms(rig_with_records(tmp_path, alone, gantry, (0.002, 0.05)), OBJECT)
    shifts = [np.sqrt(np.mean(np.sum((t.camera.project(OBJECT)[0] - rig.camera.project(OBJECT)[0]) ** 2, axis=1)))
              for t in free if t.camera is not None]  # fmt: skip
    assert np.sqrt(np.sum(np.square(shifts))) == pytest.approx(0.5 * np.sqrt(2), rel=0.05)
    terms = rig_terms(rig, OBJECT)
    lamps = [t for t in terms if t.device == "gantry"]
    assert len(lamps) == 8
    assert all(t.source == "covariance" and t.kinematics is not None for t in lamps)
    sensor = [t for t in terms if t.device == "sensor"]
    assert [t.source for t in sensor] == ["standard errors"] * 2
    assert sensor[0].sensitivity_factor == pytest.approx(1.002)
    assert sensor[1].black_level_dn == pytest.approx(rig.file.sensor.black_level_dn + 0.05)


def test_a_malformed_covariance_falls_back_to_the_records_standard_errors(tmp_path):
    """A record whose covariance is not square (a hand-edited file) is not used: its focal and principal
    point standard errors are, each an independent term, and say so; a gantry record without a covariance
    (an older hlr-lab's) gives its arm's and zeros' standard errors."""
    path = tmp_path / "with-se.toml"
    body = SIM_RIG.read_text() + (
        '\n[calibration.camera]\ndate = "2026-12-03"\nhlr_lab = "test"\ncovariance_of = ["fx_px"]\n'
        "covariance = [[1.0, 2.0]]\nfocal_se_px = [0.3, 0.3]\nprincipal_point_se_px = [0.4, 0.4]\n"
        '\n[calibration.gantry]\ndate = "2026-12-03"\nhlr_lab = "test"\narm_radius_se_mm = 0.7\n'
        "zero_ticks_se = [0.23, 0.56]\n"
    )
    path.write_text(body)
    rig = load_rig(path)
    terms = camera_terms(rig, OBJECT)
    assert terms
    assert {t.source for t in terms} == {"standard errors"}
    lamps = gantry_terms(rig)  # the arm and the two zeros, each its own term
    assert len(lamps) == 3
    assert {t.source for t in lamps} == {"standard errors"}
