"""Watching the lamp: the comparison of reference frames, the warm-up's stopping rule (on a clock of our
own), a run on the simulated rig whose lamp drifts (against the simulator's own record of its output),
and the night's figure: Rd within 1 % with the correction."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import numpy as np
import pytest

from hlr_lab.reflectance.session_fit import LampRecord
from hlr_lab.rig.file import Rig
from hlr_lab.session.lamp import (
    LampFigures,
    LampWatch,
    compared_pixels,
    lamp_at,
    lamp_watch_for,
    relative_output,
    short_of_warm,
    warm_up,
)
from tests.films import DRAWING, half_film


class FakeClock:
    """Rig time that passes only when slept."""

    def __init__(self):
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += seconds


def test_reference_frames_are_compared_over_their_well_exposed_values():
    """Per channel: a saturated colour's weak channel (here blue, 2 % of full scale) and a clipped one
    are left out; the ratio of the kept signals is the lamp's output, the black level taken off."""
    first = np.zeros((4, 4, 3), np.uint16) + 100
    first[..., 0] = 2000  # red: well exposed
    first[..., 2] = 4095  # blue: clipped
    compared = compared_pixels(first, 12, 100.0)
    assert compared[..., 0].all()
    assert not compared[..., 1:].any()
    later = first.copy()
    later[..., 0] = 100 + (2000 - 100) * 1.03
    assert relative_output(later, first, compared, 100.0) == pytest.approx(1.03, abs=1e-3)
    with pytest.raises(ValueError, match="no well-exposed"):
        relative_output(later, first, np.zeros_like(compared), 100.0)


def test_the_output_between_reference_frames_is_interpolated():
    assert lamp_at(np.zeros(0), np.zeros(0), 5.0) == 1.0  # not watched: the rig file's power
    times, outputs = np.array([10.0, 20.0]), np.array([1.0, 1.02])
    assert lamp_at(times, outputs, 15.0) == pytest.approx(1.01)
    assert lamp_at(times, outputs, 0.0) == 1.0
    assert lamp_at(times, outputs, 99.0) == 1.02
    events = [
        {"event": "lamp", "at": 1.0, "output": 1.0, "baseline": "frames/lamp_000.png"},
        {"event": "lamp", "at": 2.0, "output": 1.5, "baseline": "frames/lamp_000.png"},
        {"event": "pose", "pose": "p000"},
        {"event": "lamp", "at": 3.0, "output": 1.0, "baseline": "frames/lamp_002.png"},  # a new baseline
        {"event": "lamp", "at": 4.0, "output": 0.98, "baseline": "frames/lamp_002.png"},
    ]
    record = LampRecord.of_journal(events)
    assert record.times.tolist() == [3.0, 4.0]
    assert record.outputs.tolist() == [1.0, 0.98]


def test_the_warm_up_waits_for_the_trend_not_for_two_readings():
    """A lamp 4 % short when cold, time constant 400 s, flickering 0.1 % rms: stable within 0.2 % per
    minute once 0.04 · e^(−t/400) · 60/400 < 0.002, i.e. after ~440 s (7.3 min; the trend over the last
    four readings, a minute apart, lags by a minute and a half); a flicker between two readings does not
    stop it early; a lamp that never settles ends when the time is up."""
    clock = FakeClock()
    rng = np.random.default_rng(0)
    watch = LampWatch(warm_up_s=1800.0)

    def lamp() -> float:
        return (1 - 0.04 * np.exp(-clock.t / 400)) * (1 + 0.001 * rng.standard_normal())

    result = warm_up(lamp, watch, clock, lambda _: None)
    assert result.stable
    assert 6.5 <= result.minutes <= 11.0
    assert result.per_minute <= 0.002
    clock.t = 0.0
    never = warm_up(lambda: 1 + clock.t / 3600, LampWatch(warm_up_s=600.0), clock, lambda _: None)
    assert not never.stable
    assert never.minutes == pytest.approx(10.0)
    assert never.per_minute == pytest.approx((1 / 60) / (1 + 8.5 / 60), rel=0.01)  # over the last 4: 7–10 min


def calibrated_lamp(tmp_path: Path, record: str, *, beside: bool = False) -> Rig:
    """The drawing with a radiometric calibration record of ``record``'s lamp figures (TOML lines), and
    with ``beside`` its white reference lying beside the object during runs."""
    from hlr_lab.rig.file import load_rig

    text = DRAWING.read_text()
    if beside:
        text = text.replace("place_m = [0.0, 0.0]             # its centre at turntable 0°",
                            "place_m = [0.0, 0.0]\nrun_place_m = [0.09, 0.0]")  # fmt: skip
    path = tmp_path / "rig.toml"
    path.write_text(text + f'\n[calibration.radiometric]\ndate = "2026-12-07"\nhlr_lab = "0.1.0"\n{record}\n')
    return load_rig(path)


def test_a_lamp_the_calibration_saw_warm_up_is_warmed_up_and_watched_unless_told_otherwise(tmp_path):
    """A run's defaults follow the rig's radiometric record: a lamp 0.5 % or more below warm when first
    lit (its change over the warm-up and what it still lacked) is warmed up (at most 30 min) and watched
    every 5 poses, and the sentence says why; one that only moved over the white frames is watched; one
    steady, or a rig without the record, neither; what is given is kept; a white reference beside the
    object is the watch already."""
    warming = calibrated_lamp(tmp_path, "lamp_warm_up_change = 0.0197\nlamp_short_of_warm = 0.0098")
    watch, why = lamp_watch_for(warming)
    assert (watch.warm_up_s, watch.every) == (1800.0, 5)
    assert why is not None
    assert "warmed up (at most 30 min) and watched every 5 poses" in why
    assert "3.0 % below warm when first lit" in why
    assert "--warm-up 0 --lamp-every 0" in why
    kept, why = lamp_watch_for(warming, every=0, warm_up_s=0.0)
    assert (kept.warm_up_s, kept.every, why) == (0.0, 0, None)
    assert lamp_watch_for(warming, every=2)[0].every == 2
    # a lamp on longer before its first reading shows less change, and lacks more at the end of it
    late = calibrated_lamp(tmp_path, "lamp_warm_up_change = 0.003\nlamp_short_of_warm = 0.003")
    assert lamp_watch_for(late)[0].warm_up_s == 1800.0
    drifting = calibrated_lamp(tmp_path, "lamp_drift_over_white_frames = -0.0038")
    watch, why = lamp_watch_for(drifting)
    assert (watch.warm_up_s, watch.every) == (0.0, 5)
    assert why is not None
    assert "-0.38 % over its white frames" in why
    steady = calibrated_lamp(tmp_path, "lamp_warm_up_change = 0.002\nlamp_drift_over_white_frames = 0.0005")
    assert lamp_watch_for(steady) == (LampWatch(black_level_dn=0.0), None)
    from hlr_lab.rig.file import sim_rig

    assert lamp_watch_for(sim_rig())[1] is None
    beside = calibrated_lamp(tmp_path, "lamp_warm_up_change = 0.0197", beside=True)
    assert (lamp_watch_for(beside)[0].every, lamp_watch_for(beside)[0].warm_up_s) == (0, 1800.0)


def test_the_lamps_level_is_in_the_systematic_uncertainty_where_the_run_did_not_measure_it(tmp_path):
    """Sensitivity × power is the lamp's as the calibration left it: still ``short_of_warm`` below warm.
    A run warmed up may have had it anywhere up to warm (one σ: all of that, itself an estimate good to
    a factor of two); one neither warmed up nor watched from cold too (the warm-up's change added); one
    warmed but not watched at least the warm lamp's move over the white frames; a white reference beside
    the object measures it: no term."""
    from hlr_lab.reflectance.systematic import lamp_terms

    rig = calibrated_lamp(tmp_path, "lamp_warm_up_change = 0.02\nlamp_short_of_warm = 0.01\n"
                          "lamp_drift_over_white_frames = 0.008")  # fmt: skip

    def share(**state) -> float:
        terms = lamp_terms(rig, **state)
        assert len(terms) == 1
        assert terms[0].source == "lamp record"
        assert terms[0].sensitivity_factor is not None
        return terms[0].sensitivity_factor - 1

    assert share(watched=True, warmed=True, absolute=False) == pytest.approx(0.01)
    assert share(watched=True, warmed=False, absolute=False) == pytest.approx(0.03)
    assert share(watched=False, warmed=False, absolute=False) == pytest.approx(0.03)
    assert share(watched=False, warmed=True, absolute=False) == pytest.approx(0.01)
    drifting = calibrated_lamp(tmp_path, "lamp_short_of_warm = 0.004\nlamp_drift_over_white_frames = 0.008")
    assert lamp_terms(drifting, watched=False, warmed=True, absolute=False)[0].size == "0.8 %"  # the drift
    assert lamp_terms(rig, watched=True, warmed=True, absolute=True) == []
    from hlr_lab.rig.file import sim_rig

    assert lamp_terms(sim_rig(), watched=False, warmed=False, absolute=False) == []


@pytest.mark.parametrize(("start_steps", "readings"), [(1.0, 8), (3.0, 8), (5.0, 8), (0.0, 6), (3.0, 6)])
def test_how_far_short_of_warm_the_lamp_still_is_comes_from_its_warm_up_readings(start_steps, readings):
    """A lamp 4 % short when cold with a time constant of 6.7 warm-up steps (builtin:bench-night's: 400 s,
    read a minute apart), read six or eight times (a simulated calibration's warm-ups) from
    ``start_steps`` on: without flicker its remaining shortfall is recovered within 2 % of itself at eight
    readings (six cannot tell the time constant: within 40 %); with 0.1 % flicker the median over 21 seeded
    draws within 30 % (single draws scatter by a factor of two: the term it feeds is a σ, not a
    correction). A steady or a fading lamp is not short of warm."""
    steps = start_steps + np.arange(readings)
    level = 1 - 0.04 * np.exp(-steps / 6.67)
    truth = 1 / level[-1] - 1
    assert short_of_warm(level) == pytest.approx(truth, rel=0.02 if readings == 8 else 0.4)
    rng = np.random.default_rng(int(start_steps))
    draws = [short_of_warm(level * (1 + 0.001 * rng.standard_normal(readings))) for _ in range(21)]
    assert np.median(draws) == pytest.approx(truth, rel=0.3)
    assert short_of_warm(np.ones(8)) == pytest.approx(0.0, abs=1e-9)
    assert short_of_warm(1 - 0.01 * np.arange(8) / 8) == 0.0
    assert short_of_warm(level[:3]) == 0.0  # too few readings to tell


def test_a_straight_flickering_rise_is_not_extrapolated_without_end():
    """Six readings rising 0.5 % in a straight line under 0.1 % flicker (a simulated calibration on a
    loaded machine, whose lamp had warmed longer before its first reading): the exponential cannot tell
    its time constant, so how far short of warm it is stays within about twice the rise (a search to 100
    steps gave 19-22 %, and a run's systematic term of that size)."""
    rng = np.random.default_rng(7)
    rise = 1 + 0.005 * np.arange(6) / 5
    draws = [short_of_warm(rise * (1 + 0.001 * rng.standard_normal(6))) for _ in range(41)]
    assert max(draws) < 0.015
    assert 0.002 < np.median(draws) < 0.012


def test_the_simulated_worlds_clock_stands_still_while_a_frame_renders():
    """The world's time is the wall's × the speed factor, less the rendering: a slow host must not age
    the simulated lamp by its rendering speed (each frame ~0.5 s × 100 = a minute of lamp drift). A wait
    on it moves world time on by the wait at once."""
    from sim.clock import WorldClock

    clock = WorldClock(speed_factor=100.0)
    t0 = clock.now()
    with clock.paused():
        time.sleep(0.2)  # a render
        held = clock.now()
    assert held - t0 < 2.0  # at most the 20 ms of this machine's scheduling, × 100
    waited = time.monotonic()
    clock.sleep(30.0)
    assert time.monotonic() - waited < 0.1  # no wall time: 0.3 s at × 100 before
    assert 30.0 <= clock.now() - held < 30.0 + 5.0


DRIFTING = """[light]
type = "point"
power = 1.0
drift = { warm_up = 0.04, warm_up_s = 400.0, per_hour = -0.01, flicker = 0.001 }

[sensor]
sensitivity = 4095.0
black_level_dn = 0.0
read_noise_dn = 1.5

"""  # the drawing's sensor and lamp, the lamp drifting


def drifting_world(tmp_path: Path, radiometry: str = DRIFTING, drawing: str | None = None) -> Path:
    """The drawing (the built-in simulated rig, or the rig file text ``drawing``) with ``radiometry``'s
    [light] and [sensor], as a true rig file."""
    drawing = DRAWING.read_text() if drawing is None else drawing
    path = tmp_path / "drifting.toml"
    path.write_text(re.sub(r"(?ms)^\[light\].*?(?=^\[calibration\.board\])", radiometry, drawing))
    return path


@pytest.mark.slow
def test_a_run_measures_its_lamp_against_the_simulators_truth(tmp_path, builtin_plan, capsys):
    """Six poses, a reference frame every two: before the first, before the third and the fifth, and at
    the end; each journaled output within 0.3 % of the ratio the simulator records (its lamp_output, in
    each frame's sidecar); the fit's light scaled by it; a second run of the complete session takes none."""
    from benchmarks.acquire import repeated_poses
    from hlr_lab.cli.main import main
    from hlr_lab.formats.plan import read_plan, write_plan
    from hlr_lab.reflectance.session_fit import open_session, view_pose, view_time
    from tests.renderer_guard import require_renderer

    require_renderer()
    plan = tmp_path / "plan.json"
    write_plan(plan, repeated_poses(read_plan(builtin_plan), 6))
    command = ["acquire", "--plan", str(plan), "--sim", "--true-rig", str(drifting_world(tmp_path)),
               "--lamp-every", "2", "--out", str(tmp_path / "s"), "--speed-factor", "200"]  # fmt: skip
    assert main(command) == 0, capsys.readouterr().err
    events = [json.loads(line) for line in (tmp_path / "s" / "journal.jsonl").read_text().splitlines()]
    references = [e for e in events if e["event"] == "lamp_reference"]
    lamps = [e for e in events if e["event"] == "lamp"]
    assert len(references) == len(lamps) == 4
    truth = [
        json.loads((tmp_path / "s" / e["sidecar"]).read_text())["camera"]["lamp_output"] for e in references
    ]
    for e, true in zip(lamps, truth, strict=True):
        assert e["output"] == pytest.approx(true / truth[0], abs=0.003)
    assert lamps[-1]["output"] > 1.005  # the lamp warmed up during the run: the watch saw it

    session = open_session(tmp_path / "s")
    for view in session.views:
        assert view_pose(session, view).power == pytest.approx(session.lamp.at(view_time(view)))
    assert main(command) == 0
    again = (tmp_path / "s" / "journal.jsonl").read_text().count('"event": "lamp_reference"')
    assert again == 4  # complete: nothing taken, no reference frame either


@pytest.mark.slow
@pytest.mark.timeout(600)  # three poses and five reference frames: ~15 s quiet
def test_a_dim_reference_frame_is_taken_longer_to_compare_the_surface_not_its_highlight(
    tmp_path, builtin_plan, capsys
):
    """A sensor ten times less sensitive than the drawing's: the reference pose's own exposure leaves a
    few hundred values well exposed, mostly its highlight, so the session's first reference frame is kept
    and the next taken longer, with thousands; the outputs then follow the simulator's lamp within 0.3 %
    as at the pose's exposure on a bright frame; a resumed run compares at the exposure of its baseline."""
    from benchmarks.acquire import repeated_poses
    from hlr_lab.acquisition.poses import LAMP_REFERENCE_VALUES
    from hlr_lab.cli.main import main
    from hlr_lab.formats.plan import read_plan, write_plan
    from hlr_lab.session.frames import load_frame
    from tests.renderer_guard import require_renderer

    require_renderer()
    plan = tmp_path / "plan.json"
    write_plan(plan, repeated_poses(read_plan(builtin_plan), 3))
    dim = drifting_world(tmp_path, DRIFTING.replace("sensitivity = 4095.0", "sensitivity = 409.5"))
    command = ["acquire", "--plan", str(plan), "--sim", "--true-rig", str(dim), "--lamp-every", "1",
               "--out", str(tmp_path / "s"), "--speed-factor", "200"]  # fmt: skip
    assert main(command) == 0, capsys.readouterr().err
    events = [json.loads(line) for line in (tmp_path / "s" / "journal.jsonl").read_text().splitlines()]
    references = [e for e in events if e["event"] == "lamp_reference"]
    lamps = [e for e in events if e["event"] == "lamp"]
    first, baseline = references[0], references[1]
    pose_exposure = read_plan(plan).poses[0].exposures_s[0]
    assert first["exposure_s"] == pytest.approx(pose_exposure)
    assert 2 * pose_exposure < baseline["exposure_s"] <= 16 * pose_exposure
    assert {e["exposure_s"] for e in references[1:]} == {baseline["exposure_s"]}
    assert {e["baseline"] for e in lamps} == {baseline["file"]}
    black = 0.0
    for e, enough in ((first, False), (baseline, True)):
        pixels = load_frame(tmp_path / "s", e)
        assert (compared_pixels(pixels, e["bits"], black).sum() >= LAMP_REFERENCE_VALUES) == enough
    truth = [json.loads((tmp_path / "s" / e["sidecar"]).read_text())["camera"]["lamp_output"]
             for e in references[1:]]  # fmt: skip
    for e, true in zip(lamps, truth, strict=True):
        assert e["output"] == pytest.approx(true / truth[0], abs=0.003)
    # resumed: the last pose's frames lost and taken again, its reference frames at the baseline's exposure
    last = read_plan(plan).poses[-1].id
    for path in (tmp_path / "s" / "frames").glob(f"{last}_e*"):
        path.unlink()
    assert main(command) == 0, capsys.readouterr().err
    events = [json.loads(line) for line in (tmp_path / "s" / "journal.jsonl").read_text().splitlines()]
    again = [e for e in events if e["event"] == "lamp_reference"][len(references) :]
    assert again
    assert {e["exposure_s"] for e in again} == {baseline["exposure_s"]}


def white_reference_rigs(tmp_path: Path) -> tuple[Path, Path]:
    """The drawing with a 4 cm white reference beside the object during runs (10 cm out along +x at
    turntable 0°): the rig file hlr-lab believes, and the same as the world's true rig with a lamp that
    warms up within minutes (so that a short run sees it move)."""
    drawing = (Path(__file__).resolve().parents[1] / "hlr_lab" / "data" / "sim-rig.toml").read_text()
    believed = re.sub(r"(?m)^size_m = 0\.1$", "size_m = 0.04\nrun_place_m = [0.1, 0.0]", drawing)
    assert "run_place_m" in believed
    # slow enough that the run's poses, however long the host takes between them (world time is wall time
    # × the speed factor), fall on the warm-up's slope, not after it: with 120 s the lamp had settled by
    # the first reference on a loaded machine (range 0.0050; now 0.017 unloaded, lamp within 0.0009)
    quick = DRIFTING.replace("warm_up_s = 400.0", "warm_up_s = 600.0")
    true = re.sub(r"(?ms)^\[light\].*?(?=^\[calibration\.board\])", quick, believed)
    # at 640×480 (a quarter of the pixels to render, store and fit: the reference still covers ~900)
    (tmp_path / "rig.toml").write_text(half_film(believed))
    (tmp_path / "true.toml").write_text(half_film(true))
    return tmp_path / "rig.toml", tmp_path / "true.toml"


@pytest.mark.slow
def test_a_white_reference_beside_the_object_measures_the_lamp_in_the_poses_frames(tmp_path, capsys):
    """16 poses of builtin:pebble's plan at turntable angles 45° apart, a white reference beside the object
    and a lamp warming up: a lamp line for each pose whose frames show the reference lit (hidden behind
    the object, in its shadow or lit too steeply in the others), each within 0.3 % of the simulator's own
    record of the lamp at the frame it was measured in, in absolute terms (measured: ≤ 0.1 %); no
    reference pose is taken; a pose lost and retaken is measured as the first time; the fit's light
    follows the lines and the report says where they came from; --lamp-every is refused for such a rig,
    naming the field."""
    from hlr_lab.cli.main import main
    from hlr_lab.formats.plan import read_plan, write_plan
    from hlr_lab.reflectance.session_fit import open_session, view_pose, view_time
    from tests.renderer_guard import require_renderer

    require_renderer()
    rig, true = white_reference_rigs(tmp_path)
    planning = ["plan", "--mesh", "builtin:pebble", "--rig", str(rig), "-o", str(tmp_path / "p.json")]
    assert main(planning) in (0, 3)  # (3: fewer lights than the plain count would need)
    planned = read_plan(tmp_path / "p.json")
    poses = [planned.poses[i % len(planned.poses)].model_copy(update={"id": f"t{i:03d}",
             "turntable_deg": float((45 * i + 180) % 360 - 180)}) for i in range(16)]  # fmt: skip
    plan = tmp_path / "plan.json"
    write_plan(plan, planned.model_copy(update={"poses": poses}))
    command = ["acquire", "--plan", str(plan), "--rig", str(rig), "--sim", "--true-rig", str(true),
               "--out", str(tmp_path / "s"), "--speed-factor", "200"]  # fmt: skip
    assert main([*command, "--lamp-every", "4"]) == 1
    assert "calibration.white_reference.run_place_m" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()  # refused before anything was opened or written
    assert main(command) == 0, capsys.readouterr().err
    events = [json.loads(line) for line in (tmp_path / "s" / "journal.jsonl").read_text().splitlines()]
    assert not [e for e in events if e["event"] == "lamp_reference"]
    truth = {}
    for e in events:
        if e["event"] == "frame":
            sidecar = json.loads((tmp_path / "s" / e["sidecar"]).read_text())
            truth[sidecar["captured_at"]] = sidecar["camera"]["lamp_output"]
    lamps = [e for e in events if e["event"] == "lamp"]
    assert 4 <= len(lamps) < 16
    assert {e["baseline"] for e in lamps} == {"white reference"}
    for e in lamps:  # absolute: the world's sensitivity and power are the rig file's, so output = the lamp's
        assert e["output"] == pytest.approx(truth[e["at"]], abs=0.003), e["pose"]
    outputs = [e["output"] for e in lamps]
    assert max(outputs) - min(outputs) > 0.005, (
        outputs
    )  # the lamp warmed up during the run: the reference saw it
    run_end = [e for e in events if e["event"] == "run_end"][-1]
    assert run_end["lamp_on_reference"] == {"poses": 16, "measured": len(lamps)}
    assert f"{len(lamps)} of 16 poses" in capsys.readouterr().err  # the run's summary (on stderr) says so

    # a resumed run measures as the first did: a measured pose's frames lost and taken again give one more
    # line
    retaken = lamps[-1]["pose"]
    for path in (tmp_path / "s" / "frames").glob(f"{retaken}_e*"):
        path.unlink()
    assert main(command) == 0, capsys.readouterr().err
    events = [json.loads(line) for line in (tmp_path / "s" / "journal.jsonl").read_text().splitlines()]
    again = [e for e in events if e["event"] == "lamp"][len(lamps) :]
    assert [e["pose"] for e in again] == [retaken]
    for sidecar in (tmp_path / "s" / "frames").glob(f"{retaken}_*.json"):
        record = json.loads(sidecar.read_text())
        truth[record["captured_at"]] = record["camera"]["lamp_output"]
    assert again[0]["output"] == pytest.approx(truth[again[0]["at"]], abs=0.003)

    session = open_session(tmp_path / "s")
    assert session.lamp.on_white_reference
    for view in session.views:
        assert view_pose(session, view).power == pytest.approx(session.lamp.at(view_time(view)))
    assert main(["fit", str(tmp_path / "s")]) == 0
    assert main(["report", str(tmp_path / "s")]) == 0
    assert f"{len(lamps) + 1} measurements on it" in (tmp_path / "s" / "report.html").read_text()


NIGHT = """[light]
type = "point"
power = 0.88
drift = { warm_up = 0.04, warm_up_s = 400.0, per_hour = -0.04, flicker = 0.001 }

[sensor]
sensitivity = 3600.0
black_level_dn = 64.0
read_noise_dn = 2.2
conversion_gain_dn_per_e = 0.31

"""  # builtin:bench-night's sensor and lamp, the lamp fading four times as fast (−4 % per hour)


@pytest.mark.slow
@pytest.mark.timeout(
    1200
)  # calibration, 20-pose night, two fits: 48 s quiet (was 128 s at 40 poses in CI, loaded)
def test_the_nights_figure_rd_within_one_per_cent_with_the_correction(tmp_path, capsys):
    """The issue's figure, on the drawing's geometry with builtin:bench-night's sensor and lamp (S·Φ
    22.6 % below the nominal, the lamp cold at the start of each command, then fading, flickering — here
    −4 % per hour, four times bench-night's, so that 20 poses see a few tenths of a per cent of drift):
    `calibrate radiometric --warm-up 30`, then a 20-pose run of builtin:pebble's plan (at 640×480) that
    warms up and watches the lamp every 5 poses as that calibration's record says, then `fit`: every
    region's Rd within 1 % of the truth in absolute terms (measured 0.32 %; at −2 % per hour 0.37 %,
    0.28–0.32 % at 40 poses, 0.07–0.42 % at the full film); `fit --no-lamp-correction` differs from it by
    the lamp's measured output over the run, and the report says by how much."""
    from benchmarks.acquire import repeated_poses
    from hlr_lab.cli.main import main
    from hlr_lab.formats.materials import read_materials
    from hlr_lab.formats.plan import read_plan, write_plan
    from hlr_lab.rig.file import load_rig
    from tests.renderer_guard import require_renderer
    from worlds.plan_world import sim_scene

    require_renderer()
    world = drifting_world(tmp_path, NIGHT)
    fast = ["--sim", "--true-rig", str(world), "--speed-factor", "100"]
    full = tmp_path / "rig-full-film.toml"
    assert main(["calibrate", "radiometric", *fast, "--warm-up", "30", "--out", str(tmp_path / "rad"), "-o",
                 str(full)]) == 0, capsys.readouterr().err  # fmt: skip
    # the night itself with the camera at a quarter of the pixels, in the file and the world alike: the
    # figure is the lamp's and the radiometry's, not the film's (the sensitivity is per pixel)
    calibrated = tmp_path / "rig.toml"
    calibrated.write_text(half_film(full.read_text()))
    half_world = tmp_path / "world-half-film.toml"
    half_world.write_text(half_film(world.read_text()))
    fast = ["--sim", "--true-rig", str(half_world), "--speed-factor", "100"]
    assert main(
        ["plan", "--mesh", "builtin:pebble", "--rig", str(calibrated), "-o", str(tmp_path / "p.json")]
    ) in (0, 3)
    warmed = [json.loads(line) for line in (tmp_path / "rad" / "journal.jsonl").read_text().splitlines()]
    assert [e["stable"] for e in warmed if e["event"] == "warm_up"] == [True]
    # what it saw of the lamp (4 % short when cold, 400 s): a rise of a few per cent, and still ~1 % short
    seen = LampFigures.of(load_rig(calibrated))
    assert 0.002 < seen.warm_up_change < 0.04  # 1.0 % quiet, 0.5 % loaded: the lamp on longer before
    assert 0.005 < seen.when_lit < 0.04
    assert 0.002 < seen.short_of_warm < 0.03
    assert lamp_watch_for(load_rig(calibrated))[0].every == 5  # a run not told otherwise watches it
    plan = tmp_path / "plan.json"
    write_plan(plan, repeated_poses(read_plan(tmp_path / "p.json"), 20))
    session = tmp_path / "s"
    # neither --warm-up nor --lamp-every: the calibration's record asks for both (30 min at most, every 5)
    capsys.readouterr()
    assert main(["acquire", "--plan", str(plan), "--rig", str(calibrated), *fast, "--out", str(session)]) == 0
    said = capsys.readouterr()
    assert "the lamp is warmed up (at most 30 min) and watched every 5 poses" in said.out + said.err
    truth = dict(zip((r.id for r in read_plan(plan).object.regions), sim_scene(read_plan(plan), plan, None).materials,
                     strict=True))  # fmt: skip

    def rd(materials: Path) -> dict[int, np.ndarray]:
        return {e.id: np.array(e.rd) for e in read_materials(materials).regions}

    assert main(["fit", str(session)]) == 0
    stated = read_materials(session / "materials.json").systematic
    assert stated is not None
    assert [t.size for t in stated.terms if t.name == "lamp level (watched)"] == [
        f"{100 * seen.short_of_warm:.3g} %"
    ]
    assert main(["fit", str(session), "--no-lamp-correction", "-o", str(tmp_path / "uncorrected.json")]) == 0
    corrected, uncorrected = rd(session / "materials.json"), rd(tmp_path / "uncorrected.json")
    events = [json.loads(line) for line in (session / "journal.jsonl").read_text().splitlines()]
    outputs = [e["output"] for e in events if e["event"] == "lamp"]
    assert [e["event"] for e in events].count("warm_up") == 1
    assert len(outputs) == 5  # before the first pose, after every fifth, and at the end
    worst = max(float(np.max(np.abs(corrected[i] / truth[i].rd - 1))) for i in corrected)
    assert worst < 0.01  # 0.32 % measured
    # The correction divides each pose's light by the lamp's measured output, so without it every Rd is
    # off by a weighted mean of those outputs: within their range (± 0.05 % for the fit's own noise).
    # Not "further from the truth": with ~0.5 % of the lamp's drift in the run against the fit's ~0.3 %
    # floor, the two can cancel by chance (and did, on a loaded machine).
    low, high = min(outputs) - 1 - 5e-4, max(outputs) - 1 + 5e-4
    # the lamp did move in the run (0.23–0.36 % measured, quiet and in CI: the world's time is the host's
    # wall time outside rendering × the speed factor, so a faster host sees less of the drift)
    assert high - low > 2e-3, outputs
    for i in corrected:
        assert np.all(
            (low <= uncorrected[i] / corrected[i] - 1) & (uncorrected[i] / corrected[i] - 1 <= high)
        )
    assert main(["report", str(session)]) == 0
    page = (session / "report.html").read_text()
    assert re.search(r"without that, the poses' light would have been off by up to \d\.\d\d %", page)
    assert f"The lamp level (watched): {100 * seen.short_of_warm:.3g} % of sensitivity × power" in page
