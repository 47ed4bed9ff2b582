"""``hlr-lab bench calibration``: calibrate the simulated bench built as a true rig file while hlr-lab
believes the drawing, then measure what the calibration is worth.

1. ``calibrate all --board-along-zero`` with a 30-minute warm-up before the radiometry, through the same
   library function as the command (:func:`calibration.procedures.calibrate_all`: its photographs, rig
   files and summary pages are in the folder as the command leaves them), the rig's motion, exposures
   and warm-up clocked: the simulated-rig time (motion waits × the speed factor + exposures + the
   warm-up; rendering is not rig time); the wall time of each procedure here, photographing and solving.
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
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import tomlkit

from benchmarks.acquire import Stopwatch, TimedCamera, TimedPositioner, repeated_poses
from calibration.camera_procedure import CameraCalibration
from calibration.images import journaled_sidecars
from calibration.procedures import Calibrated, ProcedureName, Settings, calibrate_all, check_targets
from hlr_lab.errors import InputError
from hlr_lab.files import atomic_write_text
from hlr_lab.formats.plan import read_plan, write_plan
from hlr_lab.geometry.sphere import rotation_z
from hlr_lab.instrument.instruments import Instruments
from hlr_lab.object.segment import segment
from hlr_lab.pipeline import acquire_plan, fit_into, load_object, plan_object
from hlr_lab.planning.planner import PlanSettings
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


@contextlib.contextmanager
def bench_folder(out: Path | None) -> Iterator[Path]:
    """``out`` (new or empty: the photographs, rig files and sessions are kept there), or with None a
    scratch folder removed afterwards."""
    if out is None:
        with tempfile.TemporaryDirectory(prefix="hlr-bench-calibration-") as scratch:
            yield Path(scratch)
    elif out.exists() and any(out.iterdir()):
        raise InputError("the folder is not empty; give a new --out", path=out, field="--out")
    else:
        yield out


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
    drawing, figures = sim_rig(), CalibrationFigures()
    settings = Settings(views=views, board_along_zero=True, poses=poses, warm_up_min=WARM_UP)
    check_targets(drawing, ("camera", "gantry", "radiometric"))
    clocks: dict[str, RigClock] = {}

    def clocked(procedure: ProcedureName, instruments: Instruments) -> Instruments:
        progress(f"calibrate {procedure}: photographing")
        clocks[procedure] = RigClock()
        return clocks[procedure].clocked(instruments)

    outcomes: dict[str, Calibrated] = {}
    started = time.perf_counter()

    def done(c: Calibrated) -> None:
        nonlocal started
        outcomes[c.procedure] = c
        warmed_s = 60 * c.warmed.minutes if c.warmed else 0.0  # the warm-up's waits are rig time too
        figures.rig_s[c.procedure] = clocks[c.procedure].rig_seconds(speed_factor) + warmed_s
        now = time.perf_counter()
        figures.wall_s[c.procedure], started = now - started, now

    targets = SimulatedTargets(true_rig, speed_factor)
    last = calibrate_all(drawing, folder, folder / "rig-calibrated.toml", targets, settings, done=done,
                         instrumented=clocked)  # fmt: skip
    calibrated, camera = last.rig, outcomes["camera"].result
    assert isinstance(camera, CameraCalibration)
    truth = load_true_rig(true_rig)
    figures.recovery = recovery(calibrated, drawing, truth, camera.pose.rms_px)
    sidecars = journaled_sidecars(last.images, "calibrate radiometric")
    lamp_frames = [sidecar for sidecar in sidecars if sidecar["kind"] == "lamp"]
    figures.radiometric = radiometric_recovery(calibrated, truth, lamp_frames)
    watched = LampWatch(every=5, warm_up_s=60 * WARM_UP)
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
                                                  str(true_beside), speed_factor, run_poses,
                                                  LampWatch(warm_up_s=60 * WARM_UP))  # fmt: skip
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
    s, t, light = calibrated.file.sensor, truth.sensor, calibrated.file.light
    gain = s.conversion_gain_dn_per_e
    true_electrons = t.electrons_per_dn
    assert gain is not None  # the radiometric calibration wrote the gain and the power
    assert light.power is not None
    assert true_electrons is not None  # the bench's sensor has photon noise
    lamp_then = min(watched, key=lambda w: w["captured_at"])["camera"]["lamp_output"]
    return RadiometricRecovery(
        black_level_dn=abs(s.black_level_dn - t.black_level_dn),
        read_noise=abs(s.read_noise_dn / t.read_noise_dn - 1),
        conversion_gain=abs(gain * true_electrons - 1),
        sensitivity_times_power=abs(s.sensitivity * light.power / (t.sensitivity * lamp_then) - 1),
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
        rs_pct = n_pct = float("nan")
        if entry.rs is not None and entry.n is not None:  # its specular measured
            rs_pct, n_pct = _worst_pct(entry.rs, true.rs), 100 * abs(entry.n / true.n - 1)
        errors[entry.id] = RegionErrors(_worst_pct(entry.rd, true.rd), rs_pct, n_pct)
    return errors


def _worst_pct(got, true) -> float:
    return 100 * float(np.max(np.abs(np.asarray(got) / np.asarray(true) - 1)))


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


def report(
    f: CalibrationFigures, *, true_rig: str, views: int, poses: int, run_poses: int, speed_factor: float
) -> list[str]:
    """What ``hlr-lab bench calibration`` prints: times, recovery against the truth, end-to-end errors."""
    r, q = f.recovery, f.radiometric
    assert r is not None  # calibration_figures measures both before it returns
    assert q is not None
    rig_times = ", ".join(f"{name} {seconds:.0f} s" for name, seconds in f.rig_s.items())
    walls = " + ".join(f"{seconds:.0f} s" for seconds in f.wall_s.values())
    lines = [
        f"world: {true_rig}; hlr-lab starts from the drawing (the built-in simulated rig)",
        f"simulated-rig time: {rig_times} (target ≤ 5 min for camera and gantry; {views} views, {poses} lamp "
        f"poses × 2 ball places, the radiometry's warm-up included); wall here at ×{speed_factor:g} "
        f"(photographing and solving): {walls}",
        "recovery against the true rig (target):",
        f"  focal length {r.focal_pct:.3f} % (0.2 %), principal point {r.principal_point_px:.2f} px (1 px), "
        f"reprojection RMS {r.rms_px:.3f} px (0.3 px)",
        f"  camera position {r.camera_position_mm:.2f} mm (1 mm), viewing direction {r.view_direction_deg:.3f}° "
        f"(0.05°), roll {r.roll_deg:.3f}° (0.05°), turntable zero {r.turntable_zero_steps:+d} steps",
        f"  gantry zero ticks {r.gantry_zero_ticks} (2), arm radius {r.arm_radius_mm:.2f} mm (1 mm), "
        f"azimuth axis {r.azimuth_axis_deg:.3f}° (0.1°), lamp worst {r.lamp_worst_mm:.2f} mm (2 mm)",
        f"  black level {q.black_level_dn:.2f} DN (0.5 DN), read noise {100 * q.read_noise:.2f} % (5 %), "
        f"conversion gain {100 * q.conversion_gain:.2f} % (3 %), sensitivity × power "
        f"{100 * q.sensitivity_times_power:.2f} % (1 %; the lamp then {100 * q.lamp_short_of_warm:.2f} % short "
        "of its warm power: what the warm-up leaves)",
        f"end to end, builtin:pebble, {run_poses} poses, error per region in % (targets with the calibrated "
        "file: Rd 1, Rs 3, n 3):",
    ]
    for name, regions in f.end_to_end.items():
        cells = "; ".join(
            f"{rid}: Rd {e.rd_pct:.2f} Rs {e.rs_pct:.2f} n {e.n_pct:.2f}" if np.isfinite(e.rs_pct)
            else f"{rid}: Rd {e.rd_pct:.2f}, its highlight unmeasured" if np.isfinite(e.rd_pct)
            else f"{rid}: not fitted"
            for rid, e in sorted(regions.items())
        )  # fmt: skip
        worst = [  # nan: no region has that figure (no specular fitted anywhere)
            max((getattr(e, k) for e in regions.values() if np.isfinite(getattr(e, k))), default=float("nan"))
            for k in ("rd_pct", "rs_pct", "n_pct")
        ]
        lines.append(f"  {name:10}: worst Rd {worst[0]:.2f}, Rs {worst[1]:.2f}, n {worst[2]:.2f} ({cells})")
    return lines
