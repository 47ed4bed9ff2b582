"""``hlr-lab bench calibration``: calibrate the simulated bench built as a true rig file while hlr-lab
believes the drawing, then measure what the calibration is worth.

1. ``calibrate camera`` (board along the plate's zero), ``calibrate gantry`` on its result and
   ``calibrate radiometric --warm-up 30`` on that, through the same library functions as the commands,
   the rig's motion, exposures and warm-up clocked: the simulated-rig time (motion waits × the speed
   factor + exposures + the warm-up; rendering is not rig time).
2. Recovery: the calibrated rig file against the true one, turned into the world the calibration
   defines (the camera keeps its drawn azimuth about the turntable axis: docs/calibration.md); the
   sensor and the warm lamp's power in absolute terms.
3. End to end: builtin:pebble planned (its poses cycled to ``run_poses``), acquired in the true world and
   fitted, with the drawing, then with the calibrated file (the lamp warmed up and watched, as an
   overnight run would: ``--warm-up 30 --lamp-every 5``), then with the calibrated file and a 4 cm white
   reference lying beside the object in both the world and the file (``--warm-up 30``, the lamp measured
   on it in every pose); each region's worst-channel error against the simulated truth.

"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import tomlkit

from benchmarks.acquire import Stopwatch, TimedCamera, TimedPositioner, repeated_poses
from hlr_lab.files import atomic_write_text
from hlr_lab.formats.plan import read_plan, write_plan
from hlr_lab.geometry.sphere import rotation_z
from hlr_lab.instrument.control import open_rig
from hlr_lab.instrument.instruments import Instruments
from hlr_lab.object.segment import segment
from hlr_lab.pipeline import acquire_plan, fit_into, load_object, plan_object
from hlr_lab.planning.planner import PlanSettings
from hlr_lab.rig.calibrated import write_calibrated_rig
from hlr_lab.rig.file import Rig, load_rig, rig_source_path, sim_rig
from hlr_lab.session.lamp import UNWATCHED, LampWatch
from sim.rig import SimRig
from sim.true_rig import TrueRig, load_true_rig, true_rig_text
from worlds.plan_world import sim_scene, world_geometry, world_links
from worlds.targets import SimulatedTargets

OBJECT = "builtin:pebble"


@dataclass
class RigClock:
    """What the rig spent: waiting for the axes (wall seconds, at the speed factor) and exposing."""

    waiting: Stopwatch = field(default_factory=Stopwatch)
    camera: TimedCamera | None = None

    def clocked(self, i: Instruments) -> Instruments:
        """``i`` with its positioners' waits and its camera's exposures counted here."""
        self.camera = TimedCamera(i.camera, Stopwatch())
        return Instruments(TimedPositioner(i.turntable, self.waiting), TimedPositioner(i.gantry, self.waiting),
                           self.camera, i.lamp, i.thermometers, i.clock)  # fmt: skip

    def rig_seconds(self, speed_factor: float) -> float:
        """Simulated-rig time: the waits at real speed, plus the exposures (an upper bound: the drivers'
        polling between arrivals is counted as motion too)."""
        return self.waiting.seconds * speed_factor + (self.camera.exposed_s if self.camera else 0.0)


@dataclass(frozen=True)
class Recovery:
    """Calibrated against true, each in its unit (see :func:`recovery`)."""

    focal_pct: float
    principal_point_px: float
    rms_px: float
    camera_position_mm: float
    view_direction_deg: float
    roll_deg: float
    turntable_zero_steps: int
    gantry_zero_ticks: int
    arm_radius_mm: float
    azimuth_axis_deg: float
    lamp_worst_mm: float


@dataclass(frozen=True)
class RegionErrors:
    rd_pct: float  # worst channel
    rs_pct: float
    n_pct: float


@dataclass(frozen=True)
class RadiometricRecovery:
    """Calibrated against true: black level (DN), read noise, conversion gain and S·Φ (fractions)."""

    black_level_dn: float
    read_noise: float
    conversion_gain: float
    sensitivity_times_power: float  # against the lamp as it was when measured
    lamp_short_of_warm: float  # how far that lamp was below its warm power (the warm-up's criterion)


@dataclass
class CalibrationFigures:
    rig_s: dict[str, float] = field(default_factory=dict)  # per procedure: simulated-rig time
    wall_s: dict[str, float] = field(default_factory=dict)  # per procedure: wall time here
    recovery: Recovery | None = None
    radiometric: RadiometricRecovery | None = None
    end_to_end: dict[str, dict[int, RegionErrors]] = field(default_factory=dict)


WARM_UP = 30.0  # minutes at most, for the radiometric procedure and the calibrated run alike


def calibration_figures(
    folder: Path,
    *,
    true_rig: str = "builtin:bench-night",
    views: int = 24,
    poses: int = 30,
    run_poses: int = 40,
    speed_factor: float = 40.0,
    progress: Callable[[str], None] = lambda _: None,
) -> CalibrationFigures:
    """Run the three parts (module docstring) in ``folder`` (photographs, rig files, sessions kept)."""
    from calibration.camera_procedure import board_spec, capture_board_frames, load_board_frames, solve_camera
    from calibration.gantry_procedure import ball_spec, capture_ball_frames, load_ball_frames, solve_gantry
    from calibration.images import journaled_sidecars
    from calibration.radiometric_procedure import (
        capture_radiometric_frames,
        load_radiometric_frames,
        solve_radiometric,
        white_spec,
    )

    drawing, figures = sim_rig(), CalibrationFigures()
    board_spec(drawing), ball_spec(drawing), white_spec(drawing)
    warm = LampWatch(warm_up_s=60 * WARM_UP)

    def procedure(name: str, rig: Rig, world, capture) -> None:
        """Photograph ``name``'s frames into folder/name on ``rig`` in ``world`` (stack → links, and what
        else ``capture`` needs of the world), the rig's time clocked: ``capture(instruments, folder,
        world's extra)`` returns the seconds it waited besides the motion and the exposures."""
        progress(f"calibrate {name}: photographing")
        (folder / name).mkdir(parents=True)
        clock, started = RigClock(), time.perf_counter()
        with contextlib.ExitStack() as stack:
            links, extra = world(stack)
            with open_rig(rig, links) as opened:
                waited_s = capture(clock.clocked(opened.instruments), folder / name, extra)
        figures.rig_s[name] = clock.rig_seconds(speed_factor) + waited_s
        figures.wall_s[name] = time.perf_counter() - started

    def board_frames(i, out, turn) -> float:
        capture_board_frames(i, drawing, out, views=views, turn_the_wedge=turn)
        return 0.0

    targets = SimulatedTargets(true_rig, speed_factor)
    procedure("camera", drawing, lambda stack: targets.board(stack, drawing), board_frames)
    camera = solve_camera(load_board_frames(folder / "camera"), drawing)
    with_camera = write_calibrated_rig(rig_source_path(drawing), folder / "rig-camera.toml",
                                       camera.rig_fields(drawing, board_along_zero=True), "camera",
                                       camera.record(folder / "camera"))  # fmt: skip
    procedure("gantry", with_camera, lambda stack: (targets.mirror_ball(stack, with_camera), None),
              lambda i, out, _: capture_ball_frames(i, with_camera, out, poses=poses) or 0.0)  # fmt: skip
    gantry = solve_gantry(load_ball_frames(folder / "gantry"), with_camera)
    record = gantry.record(folder / "gantry")
    with_gantry = write_calibrated_rig(
        folder / "rig-camera.toml",
        folder / "rig-gantry.toml",
        gantry.rig_fields(with_camera),
        "gantry",
        record,
    )

    def radiometric_frames(i, out, _) -> float:
        warmed = capture_radiometric_frames(i, with_gantry, out, warm=warm)
        return 60 * warmed.minutes if warmed else 0.0  # the warm-up's waits are rig time too

    procedure("radiometric", with_gantry, lambda stack: (targets.white_reference(stack, with_gantry), None),
              radiometric_frames)  # fmt: skip
    radiometric = solve_radiometric(load_radiometric_frames(folder / "radiometric"), with_gantry)
    record = radiometric.record(folder / "radiometric")
    calibrated = write_calibrated_rig(
        folder / "rig-gantry.toml",
        folder / "rig-calibrated.toml",
        radiometric.rig_fields(),
        "radiometric",
        record,
    )
    truth = load_true_rig(true_rig)
    figures.recovery = recovery(calibrated, drawing, truth, camera.pose.rms_px)
    sidecars = journaled_sidecars(folder / "radiometric", "calibrate radiometric")
    lamp_frames = [sidecar for sidecar in sidecars if sidecar["kind"] == "lamp"]
    figures.radiometric = radiometric_recovery(calibrated, truth, lamp_frames)
    watched = replace(warm, every=5)
    for name, believed, lamp in (("drawing", drawing, UNWATCHED), ("calibrated", calibrated, watched)):
        progress(f"end to end with the {name} rig file: plan, acquire, fit")
        figures.end_to_end[name] = end_to_end(folder / f"e2e-{name}", believed, true_rig, speed_factor, run_poses,
                                              lamp)  # fmt: skip
    # the lamp measured on a white reference beside the object instead of a reference pose: in the true
    # world and in the calibrated file alike (absolute: docs/sessions.md, "The lamp")
    progress("end to end with the calibrated rig file and a white reference beside the object")
    beside, true_beside = folder / "rig-white-reference.toml", folder / "true-rig-white-reference.toml"
    atomic_write_text(beside, with_run_reference(rig_source_path(calibrated).read_text(encoding="utf-8")))
    atomic_write_text(true_beside, with_run_reference(true_rig_text(true_rig)))
    figures.end_to_end["white ref."] = end_to_end(folder / "e2e-white-reference", load_rig(beside),
                                                  str(true_beside), speed_factor, run_poses, warm)  # fmt: skip
    return figures


RUN_REFERENCE = {"size_m": 0.04, "run_place_m": [0.1, 0.0]}  # 4 cm, 2 cm clear of builtin:pebble's side


def with_run_reference(text: str) -> str:
    """A rig file's text with its white reference (a 0.99 one when it has none) lying beside the object
    during runs (:data:`RUN_REFERENCE`)."""
    doc = tomlkit.parse(text)
    calibration = doc.setdefault("calibration", tomlkit.table(is_super_table=True))
    reference = calibration.setdefault("white_reference", tomlkit.table())
    reference.setdefault("reflectance", [0.99, 0.99, 0.99])
    reference.update(RUN_REFERENCE)
    return tomlkit.dumps(doc)


def radiometric_recovery(calibrated: Rig, truth: TrueRig, watched: list[dict]) -> RadiometricRecovery:
    """The calibrated [sensor] and [light] against the world's sensor and its lamp as it was when S·Φ was
    referred to it (``watched``: the sidecars of the frames of the lamp from above, the first of which is
    that moment; the simulator left the lamp's output in them), and how far that lamp still was from its
    warm power."""
    s, t = calibrated.file.sensor, truth.sensor
    lamp_then = min(watched, key=lambda w: w["captured_at"])["camera"]["lamp_output"]
    return RadiometricRecovery(
        black_level_dn=abs(s.black_level_dn - t.black_level_dn),
        read_noise=abs(s.read_noise_dn / t.read_noise_dn - 1),
        conversion_gain=abs(s.conversion_gain_dn_per_e * t.electrons_per_dn - 1),
        sensitivity_times_power=abs(
            s.sensitivity * calibrated.file.light.power / (t.sensitivity * lamp_then) - 1
        ),
        lamp_short_of_warm=1 - lamp_then / truth.lamp.power,
    )


def recovery(calibrated: Rig, drawing: Rig, truth: TrueRig, rms_px: float) -> Recovery:
    """The calibrated file against the true one turned about the turntable axis by the angle that puts
    the true camera at the drawing's azimuth (the world the camera calibration defines)."""
    drawn, real = drawing.camera.centre, truth.camera.centre
    a = np.arctan2(drawn[1], drawn[0]) - np.arctan2(real[1], real[0])
    turn = rotation_z(a)[:3, :3]
    cam, k, true_k = calibrated.camera, calibrated.camera.matrix, truth.camera.matrix
    true_rotation = truth.camera.rotation @ turn.T
    g, tg = calibrated.gantry.kinematics, truth.gantry
    steps_per_degree = calibrated.turntable_kinematics.steps_per_degree
    lo, hi = np.degrees(calibrated.gantry.azimuth_limits)
    el_lo, el_hi = np.degrees(calibrated.gantry.elevation_limits)
    ticks = [g.ticks_for(az, el) for az in np.linspace(lo, hi, 19) for el in np.linspace(el_lo, el_hi, 7)]
    lamps = np.array([g.light_position(t) for t in ticks])
    true_lamps = np.array([turn @ tg.light_position(*t) for t in ticks])
    true_axis = turn @ (np.asarray(tg.azimuth_axis) / np.linalg.norm(tg.azimuth_axis))
    # the world turned by a: azimuth 0 lies where the true servo read a degrees less
    true_zero = (tg.zero_ticks[0] - g.directions[0] * np.degrees(a) * g.ticks_per_rev / 360, tg.zero_ticks[1])
    focal, true_focal = np.diag(k)[:2], np.diag(true_k)[:2]
    return Recovery(
        focal_pct=100 * float(np.max(np.abs(focal / true_focal - 1))),  # the worse of fx and fy
        principal_point_px=float(np.hypot(k[0, 2] - true_k[0, 2], k[1, 2] - true_k[1, 2])),
        rms_px=rms_px,
        camera_position_mm=1e3 * float(np.linalg.norm(cam.centre - turn @ real)),
        view_direction_deg=_angle_deg(cam.rotation[2], true_rotation[2]),
        roll_deg=_angle_deg(cam.rotation[0], true_rotation[0]),
        turntable_zero_steps=calibrated.file.turntable.zero_steps
        - round(truth.stage.zero_steps - np.degrees(a) * steps_per_degree),
        gantry_zero_ticks=round(float(np.abs(np.subtract(g.zero_ticks, true_zero)).max())),
        arm_radius_mm=1e3 * abs(g.arm_radius - tg.arm_radius),
        azimuth_axis_deg=_angle_deg(np.asarray(g.azimuth_axis) / np.linalg.norm(g.azimuth_axis), true_axis),
        lamp_worst_mm=1e3 * float(np.linalg.norm(lamps - true_lamps, axis=1).max()),
    )


def end_to_end(folder: Path, believed: Rig, true_rig: str, speed_factor: float, poses: int,
               lamp: LampWatch) -> dict[int, RegionErrors]:  # fmt: skip
    """Plan builtin:pebble on ``believed`` (its poses cycled to ``poses``), acquire it in the world built
    as ``true_rig`` with ``lamp`` watched, fit: per region the worst channel's error of Rd and Rs and the
    error of n, in per cent of the truth."""
    folder.mkdir(parents=True)
    mesh = load_object(OBJECT)
    plan, _ = plan_object(mesh, segment(mesh), believed, PlanSettings(), mesh_spec=OBJECT, plan_folder=folder)
    plan_path = folder / "plan.json"
    write_plan(plan_path, repeated_poses(plan, poses) if poses > len(plan.poses) else plan)
    plan = read_plan(plan_path)
    scene = sim_scene(plan, plan_path, None)
    with SimRig(scene=scene, speed_factor=speed_factor, **world_geometry(believed, true_rig)) as world:
        acquire_plan(
            plan_path,
            believed,
            folder / "session",
            links=world_links(world),
            lamp=lamp,
        )
    fitted = fit_into(folder / "session").materials
    truth = dict(zip((r.id for r in plan.object.regions), scene.materials, strict=True))
    errors = {rid: RegionErrors(float("nan"), float("nan"), float("nan")) for rid in truth}  # nan: not fitted
    for entry in fitted.regions:
        true = truth[entry.id]
        measured = entry.specular == "measured"
        errors[entry.id] = RegionErrors(
            rd_pct=_worst_pct(entry.rd, true.rd),
            rs_pct=_worst_pct(entry.rs, true.rs) if measured else float("nan"),
            n_pct=100 * abs(entry.n / true.n - 1) if measured else float("nan"),
        )
    return errors


def _worst_pct(got, true) -> float:
    return 100 * float(np.max(np.abs(np.asarray(got) / np.asarray(true) - 1)))


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))
