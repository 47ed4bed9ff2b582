"""``hlr-lab bench calibration`` on builtin:bench-night, once for the module (the slowest fixture of the
suite, in a file of its own so that it runs beside the rest): its ``calibrate all``'s files, the camera it
calibrated against the true one, its camera and gantry photographs solved again with ``--from``, its
figures."""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import re
import shutil
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from calibration.camera_procedure import FRAMES_PER_VIEW
from calibration.procedures import Settings
from hlr_lab.cli.main import main
from hlr_lab.rig.file import Rig, load_rig
from sim.true_rig import load_true_rig

pytestmark = pytest.mark.renderer  # the simulated rig renders its frames

SIM_RIG = Path(__file__).resolve().parents[1] / "hlr_lab" / "data" / "sim-rig.toml"
# every test's timeout: the bench is made by whichever test asks for it first. 266–317 s in CI (2 cores,
# 3 workers), 411 s with 4 workers: 1 800 s keeps 3× with another job on the same machine too
BENCH_TIMEOUT_S = 1800


@pytest.fixture(scope="module")
def night_bench(tmp_path_factory) -> tuple[Path, str]:
    """``hlr-lab bench calibration`` with the camera's default 24 views (16 leave the principal point
    1.25 px off, past its 1 px target), 12 lamp poses and 4-pose runs (the plan's 2 poses twice: with its 2
    alone the calibrated Rd came out 1.00 % off once) on builtin:bench-night, once for the module: its folder
    (what ``calibrate all`` leaves, then the runs) and what it printed. Its first part is ``calibrate all
    --board-along-zero`` with a 30-minute warm-up, through the same library function as the command."""
    folder = tmp_path_factory.mktemp("bench") / "b"
    printed = io.StringIO()
    command = [
        "bench",
        "calibration",
        "--views",
        "24",
        "--poses",
        "12",
        "--run-poses",
        "4",
        "--out",
        str(folder),
    ]
    with contextlib.redirect_stdout(printed):
        assert main(command) == 0
    return folder, printed.getvalue()


@pytest.mark.slow
@pytest.mark.timeout(BENCH_TIMEOUT_S)
def test_calibrate_all_writes_one_file_with_all_three_records(night_bench):
    """Camera, gantry, then radiometry on the simulated bench whose sensor and lamp are off too
    (builtin:bench-night), short runs: one rig file carrying all three calibrations, the intermediate
    files and every set of photographs kept in the folder. (S·Φ is that of the lamp after its warm-up:
    the drawing's sensitivity times the lamp's 88 % of nominal power, within 5 %.)"""
    folder, _ = night_bench
    after = load_rig(folder / "rig-calibrated.toml")
    assert after.file.calibration.camera is not None
    assert after.file.calibration.gantry is not None
    assert after.file.calibration.radiometric is not None
    truth = load_true_rig("builtin:bench-night")
    assert abs(after.camera.matrix[0, 0] / truth.camera.matrix[0, 0] - 1) < 0.002
    assert abs(after.gantry.kinematics.arm_radius - truth.gantry.arm_radius) < 1.5e-3
    assert abs(after.file.sensor.black_level_dn - 64.0) < 0.5
    assert after.file.sensor.conversion_gain_dn_per_e == pytest.approx(0.31, rel=0.05)
    assert after.file.sensor.sensitivity == pytest.approx(3600 * 0.88, rel=0.05)
    assert (folder / "rig-camera.toml").is_file()
    assert (folder / "rig-gantry.toml").is_file()
    assert len(list((folder / "camera" / "frames").glob("*.png"))) == 24 * FRAMES_PER_VIEW
    assert len(list((folder / "gantry" / "frames").glob("*.png"))) >= 20
    assert (folder / "camera" / "summary.html").is_file()
    assert (folder / "gantry" / "summary.html").is_file()
    positions, levels = Settings().positions, Settings().levels
    frames = folder / "radiometric" / "frames"
    kinds = Counter(json.loads(p.with_suffix(".json").read_text())["kind"] for p in frames.glob("*.png"))
    # darks at the bracket's three exposures twice, the transfer, the whites, the lamp from above twice
    assert kinds["dark"] + kinds["flat"] + kinds["reference"] + kinds["white"] + kinds["lamp"] == (
        2 * 3 + 3 * levels + positions + 2
    )
    assert kinds["warm_up"] >= 1  # and the lamp watched while it warmed up


@pytest.mark.slow
@pytest.mark.timeout(BENCH_TIMEOUT_S)
def test_bench_calibration_prints_what_calibration_is_worth(night_bench):
    """Every figure printed; the recovery within the issue's targets that a short run still reaches; the
    end-to-end error far smaller with the calibrated file than with the drawing (measured here: worst Rd
    388 % → 0.43 %, the drawing's sensor 22.6 % off and its black level 64 DN short), and with a white
    reference beside the object; camera and gantry within 5 minutes of simulated-rig time."""
    folder, printed = night_bench
    rig_s = dict(re.findall(r"(camera|gantry|radiometric) (\d+) s", printed))
    assert int(rig_s["camera"]) + int(rig_s["gantry"]) < 300
    names = ("focal length|camera position|arm radius|azimuth axis|lamp worst|black level|read noise|"
             "conversion gain|power")  # fmt: skip
    figures = dict(re.findall(rf"({names}) ([\d.]+)", printed))
    assert float(figures["focal length"]) < 0.2
    assert float(figures["camera position"]) < 1.0
    # 12 lamp poses: the arm comes out 0.9–1.04 mm off (the lamp's flicker follows the machine's pace); the
    # 1 mm target is the default 30 poses' (0.09 mm, docs/calibration.md). The short run's bound, as above
    assert float(figures["arm radius"]) < 1.5
    assert float(figures["azimuth axis"]) < 0.1
    assert float(figures["lamp worst"]) < 2.0
    assert float(figures["black level"]) < 0.5
    assert float(figures["read noise"]) < 5.0
    assert float(figures["conversion gain"]) < 3.0
    assert float(figures["power"]) < 1.0
    worst = dict(re.findall(r"(drawing|calibrated|white ref\.)\s*: worst Rd ([\d.]+)", printed))
    assert float(worst["drawing"]) > 5.0
    # Rd goes with S·Φ, whose own target is 1 % (above); a 4-pose run's fit adds ~0.3 %. Measured 0.38–0.78 %
    # (S·Φ 0.19–0.71 %: the lamp's flicker follows the machine's pace); the 1 % is the 40-pose run's
    assert float(worst["calibrated"]) < 1.5
    assert float(worst["white ref."]) < 1.0  # the lamp measured on a white reference beside the object
    assert (folder / "rig-calibrated.toml").is_file()


@pytest.mark.slow
@pytest.mark.timeout(BENCH_TIMEOUT_S)
def test_the_truth_lies_within_the_combined_uncertainty_on_the_calibrated_bench(night_bench):
    """The issue's test of the systematic part: the run fitted with the calibrated file (its records now
    carry the camera's and gantry's covariances and the radiometry's standard errors): every parameter of
    builtin:pebble's four regions against the world's truth — within 2 combined σ (√(se² + sys²)) for
    ≥ 90 % of them (measured: 28 of 28, 26 within 1σ), where the statistical σ alone covers far fewer
    (measured: 17 of 28 within 2σ; the lamp's 0.8 mm mode alone moves Rd by 30 of its standard errors)."""
    from hlr_lab.formats.materials import read_materials
    from hlr_lab.formats.plan import read_plan
    from worlds.plan_world import sim_scene

    folder, _ = night_bench
    records = load_rig(folder / "rig-calibrated.toml").file.calibration
    for record in (records.camera, records.gantry):
        assert record is not None
        assert "covariance" in (record.model_extra or {})
    assert records.radiometric is not None
    assert {"sensitivity_se_rel", "black_level_se_dn"} <= set(records.radiometric.model_extra or {})
    run = folder / "e2e-calibrated"
    plan = read_plan(run / "plan.json")
    truth = dict(zip((r.id for r in plan.object.regions), sim_scene(plan, run / "plan.json", None).materials,
                     strict=True))  # fmt: skip
    materials = read_materials(run / "session" / "materials.json")
    assert materials.systematic is not None
    assert materials.systematic.uncalibrated is None
    combined, alone = [], []
    for e in materials.regions:
        t = truth[e.id]
        assert e.rd_sys is not None
        assert e.rs is not None
        assert e.rs_se is not None
        assert e.rs_sys is not None
        assert e.n is not None
        assert e.n_se is not None
        assert e.n_sys is not None
        for got, se, sys, true in ((e.rd, e.rd_se, e.rd_sys, t.rd), (e.rs, e.rs_se, e.rs_sys, t.rs),
                                   ([e.n], [e.n_se], [e.n_sys], [t.n])):  # fmt: skip
            err = np.abs(np.subtract(got, true))
            combined += list(err <= 2 * np.hypot(se, sys))
            alone += list(err <= 2 * np.asarray(se))
    assert len(combined) == 28
    assert np.mean(combined) >= 0.9, np.mean(combined)
    assert np.mean(alone) < np.mean(combined)


@pytest.mark.slow
@pytest.mark.timeout(BENCH_TIMEOUT_S)
def test_calibrate_gantry_on_the_camera_calibrated_rig(night_bench, tmp_path, capsys):
    """`calibrate gantry` on the rig file `calibrate camera` wrote, solved again with --from from the
    photographs the bench's `calibrate all` took of the mirror ball (12 lamp poses, in builtin:bench-night:
    bench-offsets' geometry): the arm and zero ticks move to the true ones (in the camera-defined world
    the azimuth zero is the true one turned with it: 2062 + 3 ticks), the azimuth limits narrowed to fit
    one servo turn about the new zero, a [calibration.gantry] record beside the camera's, the same as the
    bench's own solve; a rig file without a mirror ball is refused."""
    folder, _ = night_bench
    command = ["calibrate", "gantry", "--rig", str(folder / "rig-camera.toml"), "--from", str(folder / "gantry"),
               "-o", str(tmp_path / "gantry.toml")]  # fmt: skip
    assert main(command) == 0, capsys.readouterr().err
    after = load_rig(tmp_path / "gantry.toml")
    truth = load_true_rig("builtin:bench-night").gantry
    k = after.gantry.kinematics
    assert abs(k.arm_radius - truth.arm_radius) < 1.5e-3
    assert abs(k.zero_ticks[0] - (truth.zero_ticks[0] + 3)) <= 3
    assert abs(k.zero_ticks[1] - truth.zero_ticks[1]) <= 3
    assert after.file.gantry.azimuth_limits_deg[1] < 180.0  # the zero moved: ±180° no longer fits one turn
    assert after.file.calibration.gantry.rays >= 20
    assert after.file.calibration.camera is not None  # the camera's record is kept
    bench = load_rig(folder / "rig-gantry.toml").gantry.kinematics
    assert k.arm_radius == pytest.approx(bench.arm_radius, rel=1e-6)  # solver noise only
    page = (folder / "gantry" / "summary.html").read_text()  # both outlines, every highlight used
    assert page.count("<img ") == 2 + after.file.calibration.gantry.rays
    assert "the ball where the fit puts it" in page
    text = SIM_RIG.read_text()
    bare = tmp_path / "bare.toml"
    bare.write_text(text[: text.index("[calibration.mirror_ball]")])
    assert main(["calibrate", "gantry", "--rig", str(bare), "--sim", "-o", str(tmp_path / "x.toml")]) == 1
    assert "no [calibration.mirror_ball]" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.timeout(BENCH_TIMEOUT_S)
def test_the_calibrated_camera_is_the_true_one(night_bench, rig: Rig):
    """The camera ``calibrate all`` measured first (rig-camera.toml), against the true rig, in the world
    whose +x the camera's drawn azimuth defines (a turn about the turntable axis no photograph of the
    turntable can see): focal length 0.2 %, principal point 1 px, RMS 0.3 px, position 1 mm, viewing
    direction and roll 0.05° (the issue's targets); the turntable's zero from the board along the plate's
    0° line; the rest of the operator's file kept."""
    folder, _ = night_bench
    after = load_rig(folder / "rig-camera.toml")
    true_rig = load_true_rig("builtin:bench-night")
    truth = true_rig.camera
    k, true_k = after.camera.matrix, truth.matrix
    assert abs(k[0, 0] / true_k[0, 0] - 1) < 0.002
    assert abs(k[1, 1] / true_k[1, 1] - 1) < 0.002
    assert np.hypot(k[0, 2] - true_k[0, 2], k[1, 2] - true_k[1, 2]) < 1.0
    drawn, real = rig.camera.centre, truth.centre
    a = np.arctan2(drawn[1], drawn[0]) - np.arctan2(real[1], real[0])
    turn = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    true_rotation, true_centre = truth.rotation @ turn.T, turn @ real
    assert np.linalg.norm(after.camera.centre - true_centre) < 1e-3
    for row in (0, 2):  # the image's x axis (roll) and the optical axis
        assert np.degrees(np.arccos(min(1.0, after.camera.rotation[row] @ true_rotation[row]))) < 0.05
    # the simulated board stands along the plate's 0° line: in the world turned by a (−0.28°), the plate's
    # 0° line lies at a, so the turntable's zero is the true one (20 steps) less a: 48 steps
    true_zero = true_rig.stage.zero_steps - round(np.degrees(a) * 100)
    assert abs(after.file.turntable.zero_steps - true_zero) <= 2
    # the limits follow the zero: no goal beyond the stage steps the drawing's ±180° allowed
    t = after.turntable_kinematics
    assert [t.steps_for(d) for d in after.file.turntable.limits_deg] == [-18000 + t.zero_steps, 18000]
    record = after.file.calibration.camera
    assert record is not None
    assert record.rms_px <= 0.3
    assert record.views_used == record.views == 24
    # the rest of the operator's file is kept, comments included
    text = (folder / "rig-camera.toml").read_text()
    assert "# OpenCV intrinsics; the principal point is off-centre on purpose" in text
    assert after.file.gantry == rig.file.gantry  # what the camera procedure does not measure is kept


@pytest.mark.slow
@pytest.mark.timeout(BENCH_TIMEOUT_S)
def test_the_camera_photographs_are_solved_again_without_the_rig(night_bench, tmp_path, capsys):
    """``calibrate camera --from`` the bench's camera photographs: the same camera; their summary page
    self-contained, every view with its corners and RMS; handed to the gantry's solve, refused, nothing
    written."""
    folder, _ = night_bench
    photographs = folder / "camera"
    again = tmp_path / "again.toml"
    assert main(["calibrate", "camera", "--sim", "--from", str(photographs), "-o", str(again)]) == 0
    first, second = load_rig(folder / "rig-camera.toml"), load_rig(again)
    np.testing.assert_allclose(second.camera.matrix, first.camera.matrix, rtol=1e-6)  # solver noise only
    assert "photographs in" in capsys.readouterr().err
    page = (photographs / "summary.html").read_text()
    assert page.count("<img ") == 24  # (four photographs a view, averaged: 0.06 px, half of one's 0.12)
    assert (
        len(re.findall(r"<figcaption>view \d+: turntable -?[\d.]+°, wedge face [01], RMS 0\.0\d\d px", page))
        == 24
    )
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", page)
    wrong = ["calibrate", "gantry", "--rig", str(folder / "rig-camera.toml"), "--from", str(photographs),
             "-o", str(tmp_path / "g.toml")]  # fmt: skip
    assert main(wrong) == 1
    assert "not the photographs of hlr-lab calibrate gantry" in capsys.readouterr().err
    assert not (tmp_path / "g.toml").exists()
    assert len(list((photographs / "frames").glob("*.png"))) == 24 * FRAMES_PER_VIEW


@pytest.mark.slow
@pytest.mark.timeout(BENCH_TIMEOUT_S)
def test_a_view_whose_photographs_disagree_on_where_it_was_is_refused(night_bench, tmp_path, capsys):
    """The photographs of one view are averaged: one of them journaled at other turntable steps (a careless
    hand, checksums made good) is refused naming the view, and nothing is written."""
    images = tmp_path / "images"
    shutil.copytree(night_bench[0] / "camera", images)
    journal = images / "journal.jsonl"
    events = [json.loads(line) for line in journal.read_text().splitlines()]
    e = next(e for e in events if e["event"] == "frame" and e["pose"] == "v03" and e["exposure_index"] == 2)
    sidecar = images / e["sidecar"]
    data = json.loads(sidecar.read_text())
    data["turntable_steps"] += 500
    sidecar.write_text(json.dumps(data))
    e["sidecar_sha256"] = hashlib.sha256(sidecar.read_bytes()).hexdigest()
    journal.write_text("".join(json.dumps(x) + "\n" for x in events))
    assert main(["calibrate", "camera", "--sim", "--from", str(images), "-o", str(tmp_path / "c.toml")]) == 1
    assert "view v03's photographs were taken at different turntable steps" in capsys.readouterr().err
    assert not (tmp_path / "c.toml").exists()


def test_the_end_to_end_line_says_which_regions_had_no_highlight_measured_and_which_no_fit():
    """A region fitted without its highlight shows its Rd and says the highlight was not measured (no
    "nan"); a region not fitted at all says so; the worst figures are over the regions that have them."""
    from benchmarks.calibration import CalibrationFigures, RadiometricRecovery, Recovery, RegionErrors, report

    figures = CalibrationFigures(
        {"camera": 31.0}, {"camera": 49.0},
        Recovery(0.01, 0.7, 0.07, 0.06, 0.016, 0.015, 0, 0, 0.58, 0.003, 0.67),
        RadiometricRecovery(0.0, 0.0064, 0.004, 0.0034, 0.0094),
        {"drawing": {0: RegionErrors(126.8, float("nan"), float("nan")), 1: RegionErrors(11.0, 10.0, 9.0),
                     2: RegionErrors(float("nan"), float("nan"), float("nan"))}},
    )  # fmt: skip
    (line,) = (x for x in report(figures, true_rig="t", views=24, poses=30, run_poses=4, speed_factor=40)
               if x.lstrip().startswith("drawing"))  # fmt: skip
    assert "nan" not in line, line
    assert "worst Rd 126.80, Rs 10.00, n 9.00" in line
    assert "0: Rd 126.80, its highlight unmeasured; 1: Rd 11.00 Rs 10.00 n 9.00; 2: not fitted" in line
