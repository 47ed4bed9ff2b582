"""``hlr-lab fit``: a session directory → per-region materials and diagnostics.

Streams pose by pose: one bracket's frames are read, merged into radiance, turned into samples and
dropped, so memory is bounded by a few frames plus the samples kept (tens of bytes each). The frames of
one pose taken in different runs (a resumed session) can have slightly different measured positions:
they form separate views, each with its own geometry.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np

from hlr_lab.errors import InputError
from hlr_lab.fitting import (
    DEFAULT_ESTIMATOR,
    DegenerateSamples,
    EstimatorName,
    InsufficientSamples,
    RegionFit,
    fit_region,
    fit_shift,
)
from hlr_lab.fitting.diffuse_only import BETA_DEG as DIFFUSE_BETA_DEG
from hlr_lab.fitting.diffuse_only import (
    DiffuseCutoff,
    diffuse_cutoff,
    least_squares_rd,
    rd_standard_error,
)
from hlr_lab.fitting.inputs import MIN_DIFFUSE, normal_mad
from hlr_lab.formats.materials import (
    MaterialEntry,
    MaterialsFile,
    NotMeasured,
    PixelCounts,
    materials_file,
    measured_entry,
    unmeasured_entry,
)
from hlr_lab.formats.plan import PlanFile
from hlr_lab.formats.planned_object import load_planned_mesh, mesh_to_turntable
from hlr_lab.formats.regions import RegionEntry
from hlr_lab.geometry.silhouette import object_window
from hlr_lab.object.grouping import group_rows
from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.object.raycast import RayCaster
from hlr_lab.reflectance.alignment import PoseAlignment, pose_alignment
from hlr_lab.reflectance.hdr import BracketFrame, Radiance, exposure_agreement, merge_bracket
from hlr_lab.reflectance.systematic import RigTerm, lamp_terms, placement_note, placement_terms, rig_terms
from hlr_lab.reflectance.views import (
    DEFAULT_SELECTION,
    PixelGeometry,
    PoseGeometry,
    PoseSamples,
    Selection,
    StageTimes,
    light_terms_again,
    pose_geometry,
    pose_samples,
)
from hlr_lab.rig.file import Rig, rig_of_snapshot
from hlr_lab.session.frames import checked_sidecar, load_frame
from hlr_lab.session.journal import JOURNAL, load_journal
from hlr_lab.session.lamp import WHITE_REFERENCE, lamp_at
from hlr_lab.session.metadata import SESSION, read_record, session_plan
from hlr_lab.session.stages import current_plan

MATERIALS, DIAGNOSTICS = "materials.json", "fit-diagnostics.json"  # written into the session by default
DIAGNOSTICS_FORMAT = "hlr-lab.fit-diagnostics"
# fit --radiance: each pose's merged radiance as POSE.exr, in this folder beside materials.json
RADIANCE = "radiance"
SIGNIFICANT = 5.0  # a fitted Rs below this many standard errors is no highlight seen
CLEAR_OF_NOISE = 3.0  # pixels whose mean is below this many noise σ are too dark to say whether they are lit
BELOW_BLACK = 3.0  # an Rd this many standard errors below 0 is no near-black surface: the pixels are wrong
# a bracket's frames may disagree about radiance by this much (relative) before they are refused: a linear
# sensor under a steady lamp agrees within 1 % (the simulated rig: 1.000–1.008); two exposures of the default
# bracket swapped disagree by 4× and 16×, any two confused by at least their ratio (≥ 2 in a useful bracket)
EXPOSURE_TOLERANCE = 0.2
# a region's diffuse pixels must follow the light that falls on them (Pearson r of pixel and L·cos α) at
# least this well: a lit matte surface gives r > 0.95; a dead lamp, a uniform frame or another object ~0
FOLLOWS_LIGHT = 0.5
SPREAD = 0.05  # … judged only where L·cos α varies by this much (relative σ): else noise decides r
# a black level this far (DN) from the rig file's, as the brackets tell it, is worth a warning: the
# brackets measure it within ~0.2 DN on the simulated rig (1.5 DN read noise)
BLACK_LEVEL_WARNING_DN = 2.0
# a patch of surface whose pixels share what the model misses (surface_patches): on 30 held-out scenes
# (bench materials) Rd within 2 SE for 87 % of parameters counting pixels and 2 mm patches, 91 % with 5 mm
# and with 10 mm (docs/fitting.md, "Standard errors")
PATCH_M = 5e-3
_NUDGE = 1e-3  # the fraction of a systematic term the fit's linearisation is taken over (_systematic_shifts)


@dataclass(frozen=True, eq=False)
class View:
    """One pose's bracket as taken: its frames' journal lines and the measured positions they share."""

    pose: str
    measured: dict
    frames: list[dict]  # journal lines, lit frames
    darks: dict[int, dict]  # exposure index → journal line of the dark frame
    sidecars: dict[str, dict] = field(default_factory=dict)  # frame file → its checked sidecar


@dataclass(frozen=True)
class Gaps:
    """What of a session cannot be used, and why: journal lines that are damaged, frames whose files or
    sidecars do not agree with their journal line, and planned frames that are not there at all."""

    damaged_lines: list[str] = field(default_factory=list)  # "line 17: not JSON (…)"
    rejected_frames: list[str] = field(default_factory=list)  # "frames/p001_e0.png: …"
    missing_frames: list[str] = field(default_factory=list)  # "p001 exposure 0"

    def notes(self) -> list[str]:
        """One line per unusable journal line or frame, for the operator."""
        return [f"{JOURNAL} {d}" for d in self.damaged_lines] + self.rejected_frames

    def as_record(self) -> dict:
        return {k: v for k, v in asdict(self).items() if v}


@dataclass(frozen=True, eq=False)
class Session:
    """A session folder opened for fitting (:func:`open_session`): its plan and the rig as recorded when
    it was acquired, the views whose frames checked out (one per pose: its exposures and dark frames),
    ``record`` (``session.json``), what is missing (``gaps``) and the lamp's measured output (``lamp``)."""

    path: Path
    plan: PlanFile
    plan_path: Path
    rig: Rig
    views: list[View]
    record: dict  # session.json
    gaps: Gaps = Gaps()
    lamp: LampRecord = field(default_factory=lambda: LampRecord.unwatched())


@dataclass(frozen=True, eq=False)
class LampRecord:
    """The lamp's output through the run, relative to the session's baseline reference frame
    (:mod:`hlr_lab.session.lamp`): Unix times (K,) and outputs (K,); empty when the run did not watch it."""

    times: np.ndarray
    outputs: np.ndarray
    on_white_reference: bool = False  # measured on the white reference in the poses' own frames
    warmed: bool = False  # the run warmed the lamp up first (a ``warm_up`` line)

    @classmethod
    def unwatched(cls, warmed: bool = False) -> LampRecord:
        """No measurement: every pose under the rig file's power."""
        return cls(np.zeros(0), np.zeros(0), warmed=warmed)

    @classmethod
    def of_journal(cls, events: list[dict]) -> LampRecord:
        """The ``lamp`` lines measured against the latest baseline (a resumed run whose baseline frame was
        lost starts another; the poses before it then take the nearest later measurement)."""
        warmed = any(e.get("event") == "warm_up" for e in events)
        lines = [e for e in events if e.get("event") == "lamp"]
        if not lines:
            return cls.unwatched(warmed)
        baseline = lines[-1].get("baseline")
        kept = sorted((e["at"], e["output"]) for e in lines if e.get("baseline") == baseline)
        times, outputs = (np.array(v, float) for v in zip(*kept, strict=True))
        return cls(times, outputs, baseline == WHITE_REFERENCE, warmed)

    @property
    def watched(self) -> bool:
        """Whether the run measured the lamp at all (reference frames or a white reference beside)."""
        return len(self.times) > 0

    def at(self, t: float) -> float:
        return lamp_at(self.times, self.outputs, t)


@dataclass
class _Pooled:
    """One region's samples over all views, kept compact (float32: ~90 bytes a sample, the fit's only
    memory that grows with the session): each part one view's (its index in ``Session.views``), and how
    many came from each view."""

    parts: list[tuple[int, PoseSamples]] = field(default_factory=list)
    per_view: dict[str, int] = field(default_factory=dict)

    def add(self, index: int, view: str, samples: PoseSamples, mask: np.ndarray) -> None:
        self.parts.append((index, samples.compact(mask)))
        self.per_view[view] = self.per_view.get(view, 0) + int(mask.sum())

    def stacked(self, name: str) -> np.ndarray:
        if name == "footprint":
            return np.concatenate([p.footprint.nodes for _, p in self.parts]).astype(np.float64)
        return np.concatenate([getattr(p, name) for _, p in self.parts]).astype(np.float64)

    def inputs(self) -> _Inputs:
        """The fit's inputs, stacked over the views (float64)."""
        return _Inputs(*(self.stacked(name) for name in _Inputs._fields))

    def any_light(self) -> bool:
        """Whether any of the region's pixels read above black (without stacking them)."""
        return any(bool(np.any(p.intensity > 0)) for _, p in self.parts)


class _Inputs(NamedTuple):
    """A region's fit inputs (``fit_region``'s): intensity (N, C), irradiance, cos α, cos β (N,), the
    footprint's log cos β (N, 4)."""

    intensity: np.ndarray
    irradiance: np.ndarray
    cos_alpha: np.ndarray
    cos_beta: np.ndarray
    footprint: np.ndarray


# how a region's entry moves when its inputs do: (7,) the change of (Rd[3], Rs[3], n), NaN where the entry
# has no such number
Respond = Callable[[_Inputs], np.ndarray]


# a lamp that lit nothing: what to look at
_DARK_ADVICE = "check that it is connected and switched by the rig, the exposures, and the lens cap"
_BELOW_BLACK = "the pixels read darker than black"
_BLACK_LEVEL_ADVICE = "check [sensor] black_level_dn against dark frames (hlr-lab calibrate radiometric)"
_POWER_ADVICE = "check [sensor] sensitivity and [light] power (hlr-lab calibrate radiometric)"


@dataclass(frozen=True)
class MisfitAdvice:
    """What to check first when a region's pixels do not follow the model: its Rd below black
    (``below_black``), or a reflectance above what the lamp can give (``too_bright``)."""

    below_black: str = f"{_BELOW_BLACK}; {_BLACK_LEVEL_ADVICE}"
    too_bright: str = _POWER_ADVICE


def misfit_advice(black_level: dict, alignment: dict) -> MisfitAdvice:
    """The advice for pixels that do not follow the model, from what the session's own photographs tell
    (``fit-diagnostics.json``'s ``black_level`` and ``alignment``): an object the photographs show off where
    the plan puts it is named first (its regions' pixels are then other surfaces', or the plate); then a
    black level the exposure brackets put off the rig file's; where the brackets agree with the rig file,
    the black level is not the cause and the advice says so."""
    flagged = alignment.get("flagged", [])
    if flagged:
        misplaced = (
            f"the photographs of {len(flagged)} pose(s) show the object off where the plan puts it "
            "(fit-diagnostics.json's alignment), so this region's pixels are partly other surfaces': run "
            "hlr-lab register and acquire the placed plan"
        )
        return MisfitAdvice(f"{_BELOW_BLACK}: {misplaced}", misplaced)
    if "warning" in black_level:
        return MisfitAdvice(
            f"{_BELOW_BLACK}: the exposure brackets put the sensor's black level {black_level['offset_dn']:+.1f} "
            f"DN from the rig file's [sensor] black_level_dn = {black_level['rig_dn']:g}; measure it (hlr-lab "
            "calibrate radiometric)"
        )
    if black_level.get("brackets"):
        return MisfitAdvice(
            f"{_BELOW_BLACK}, though the exposure brackets agree with the rig file's black level (within "
            f"{abs(black_level['offset_dn']):.1f} DN over {black_level['brackets']} brackets): check light from "
            "elsewhere (dark frames), the rig file's camera and gantry (hlr-lab calibrate) and that the object "
            "photographed is the plan's, where the plan puts it (hlr-lab register)"
        )
    return MisfitAdvice()


@dataclass(frozen=True)
class FitStep:
    """Progress: item ``index`` of ``total`` in ``stage`` ("poses", then "regions") is being worked on."""

    stage: str
    index: int
    total: int
    label: str


@dataclass(frozen=True)
class FitResult:
    """What :func:`fit_session` measured: ``materials.json``'s contents, the per-region diagnostics
    (``fit-diagnostics.json``), each measured region's full fit, and the seconds each stage took."""

    materials: MaterialsFile
    diagnostics: dict
    fits: dict[int, RegionFit]  # the regions whose specular was measured
    seconds: dict[str, float]  # per stage: hdr, g-buffer, selection, shadows, fitting


def open_session(path: Path, *, allow_incomplete: bool = False, correct_lamp: bool = True) -> Session:
    """Read ``session.json`` and the journal: the plan, the rig as recorded, and the views. Every frame
    is checked against its journal line; a session missing planned frames is refused (saying which and
    why) unless ``allow_incomplete``, and then :attr:`Session.gaps` says what is missing. The lamp's
    measured output (when the run watched it) scales each view's light unless not ``correct_lamp``."""
    record = read_record(path)
    journal = load_journal(path / JOURNAL)
    plan, plan_path = current_plan(path, session_plan(path, record), journal.events)
    rig = rig_of_snapshot(record["rig"]["snapshot"], f"{path / SESSION} (rig snapshot)")
    views, rejected = _views(path, journal.events, {p.id for p in plan.poses})
    have = {(v.pose, e["exposure_index"]) for v in views for e in v.frames}
    missing = [
        f"{p.id} exposure {k}" for p in plan.poses for k in range(len(p.exposures_s)) if (p.id, k) not in have
    ]
    gaps = Gaps([d.describe() for d in journal.damaged], rejected, missing)
    if missing and not allow_incomplete:
        shown = ", ".join(missing[:6]) + (f" and {len(missing) - 6} more" if len(missing) > 6 else "")
        why = "; ".join(gaps.notes()[:3]) or "the run stopped before them"
        raise InputError(
            f"{len(missing)} planned frame(s) are not in the session ({shown}); why: {why}. Run hlr-lab "
            "acquire on this session again to take them, or fit with --allow-incomplete",
            path=path,
        )
    lamp = LampRecord.of_journal(journal.events) if correct_lamp else LampRecord.unwatched()
    return Session(path, plan, plan_path, rig, views, record, gaps, lamp)


def _views(path: Path, events: list[dict], planned: set[str]) -> tuple[list[View], list[str]]:
    """The journaled frames of the ``planned`` poses that check out (files there, sidecar checksum, sidecar
    agreeing with the journal line; each image's checksum when it is read), grouped into views, and what was
    wrong with the others. Of the lines for one frame (pose, exposure,
    lamp), the last intact one counts (a resumed run retakes a lost frame under a new name)."""
    latest: dict[tuple[str, int, bool], tuple[dict, dict]] = {}
    rejected = []
    for e in events:
        if e.get("event") != "frame":
            continue
        sidecar, problem = checked_sidecar(path, e)  # the image's checksum is checked as it is read
        if sidecar is not None and problem is None:
            problem = _sidecar_problem(sidecar)
        if problem is None and e["pose"] not in planned:  # no planned pose, no geometry
            problem = f"its pose {e['pose']!r} is not in the session's plan"
        if problem is not None or sidecar is None:
            rejected.append(f"{e['file']}: {problem or 'no sidecar'}")
        else:
            latest[(e["pose"], e["exposure_index"], e["dark"])] = (e, sidecar)
    groups: dict[tuple[str, str], View] = {}
    for (pose, k, dark), (e, sidecar) in latest.items():
        view = groups.setdefault(
            (pose, json.dumps(sidecar["measured"], sort_keys=True)), View(pose, sidecar["measured"], [], {})
        )
        if dark:
            view.darks[k] = e
        else:
            view.frames.append(e)
            view.sidecars[e["file"]] = sidecar
    return [v for v in groups.values() if v.frames], rejected


def _sidecar_problem(sidecar: dict) -> str | None:
    """What makes a sidecar's numbers unusable (they set the geometry and the radiometry), or None."""
    m = sidecar.get("measured")
    checks = (
        ("measured.turntable_steps", isinstance(m, dict) and _register(m.get("turntable_steps"))),
        ("measured.gantry_ticks", isinstance(m, dict) and isinstance(m.get("gantry_ticks"), list)
         and len(m["gantry_ticks"]) == 2 and all(_register(t) for t in m["gantry_ticks"])),
        ("exposure_s", _finite(sidecar.get("exposure_s"), 0, 3600)),
        ("gain_db", _finite(sidecar.get("gain_db"), 0, 60, closed=True)),
        ("bits", type(sidecar.get("bits")) is int and 1 <= sidecar["bits"] <= 16),
    )  # fmt: skip
    bad = [name for name, ok in checks if not ok]
    return f"its sidecar has no usable {', '.join(bad)}" if bad else None


def _register(v) -> bool:
    """A position a drive can report: an integer in a signed 32-bit register (the Modbus stage's two
    words, a Dynamixel's Present Position); 10¹⁵ steps is no reading."""
    return type(v) is int and -(2**31) <= v < 2**31


def _finite(v, lo: float, hi: float, *, closed: bool = False) -> bool:
    return type(v) in (int, float) and math.isfinite(v) and (lo <= v if closed else lo < v) and v <= hi


@dataclass(frozen=True, eq=False)
class PoseRadiance:
    """A pose as the fit saw it: its view, its measured light, its merged radiance and ``used`` (H, W) bool,
    the pixels the fit took from it."""

    view: View
    pose: PoseGeometry
    radiance: Radiance
    used: np.ndarray


def view_radiance(session: Session, view: View, mesh: ColouredMesh) -> Radiance:
    """The view's bracket merged into linear radiance with the rig's radiometric calibration, where the
    object (``mesh``, turntable frame) may appear. A bracket whose frames contradict their recorded
    exposures (:func:`~hlr_lab.reflectance.hdr.exposure_agreement` beyond ``EXPOSURE_TOLERANCE``) is
    refused, naming its frames: merged, it would give every pixel a wrong radiance."""
    sensor = session.rig.file.sensor
    frames = [
        bracket_frame(
            session.path, e, view.sidecars[e["file"]], view.darks.get(e["exposure_index"]), session.rig
        )
        for e in view.frames
    ]
    within = object_window(session.rig.camera, mesh.vertices, view_pose(session, view).turntable_deg)
    noise = {"black_level_dn": sensor.black_level_dn, "read_noise_dn": sensor.read_noise_dn}
    agreement = exposure_agreement(frames, **noise, within=within)
    for pair in agreement:
        if not (pair.ratio > 0 and abs(math.log(pair.ratio)) <= math.log1p(EXPOSURE_TOLERANCE)):
            a, b = view.frames[pair.longer], view.frames[pair.shorter]
            raise InputError(
                f"{a['file']} ({frames[pair.longer].exposure_s:g} s) is {pair.ratio:.3g}× as bright per second of "
                f"exposure as {b['file']} ({frames[pair.shorter].exposure_s:g} s) of the same pose, where a linear "
                "camera under a steady lamp gives 1: the frames are not the exposures their sidecars record "
                f"(swapped, or the lamp changed within the bracket). Delete pose {view.pose}'s frames to have "
                "hlr-lab acquire retake them",
                path=session.path,
            )
    merged = merge_bracket(frames, sensitivity=sensor.sensitivity, **noise, within=within)
    return replace(merged, agreement=tuple(agreement))


def view_pose(session: Session, view: View) -> PoseGeometry:
    """The turntable angle and lamp position the axes measured for this view, and the lamp's power then
    (the rig file's, times the output the run measured at the view's time)."""
    rig = session.rig
    return PoseGeometry(
        rig.turntable_kinematics.degrees_for(view.measured["turntable_steps"]),
        rig.gantry.kinematics.light_position(tuple(view.measured["gantry_ticks"])),
        rig.file.light.power * session.lamp.at(view_time(view)),
        rig.gantry.centre if rig.file.light.type == "directional" else None,
    )


def view_time(view: View) -> float:
    """When the view was taken: the mean Unix time its frames arrived."""
    return float(np.mean([s["captured_at"] for s in view.sidecars.values()]))


def placed_mesh(session: Session) -> ColouredMesh:
    """The plan's mesh (checked by sha256) in the turntable frame."""
    return load_planned_mesh(session.plan, session.plan_path).transformed(mesh_to_turntable(session.plan))


def fit_session(
    session: Session,
    *,
    theta_c_deg: float | Literal["auto"] = "auto",
    method: EstimatorName = DEFAULT_ESTIMATOR,
    selection: Selection = DEFAULT_SELECTION,
    systematic: bool = True,
    progress: Callable[[FitStep], None] = lambda _: None,
    on_radiance: Callable[[PoseRadiance], None] | None = None,
) -> FitResult:
    """Fit every region of ``session``: each view's frames merged to radiance (HDR), its pixels placed
    on the mesh and kept or left out (``selection``: grazing light or view, borders, shadows), pooled per
    region over the views, then ``method``'s Phong fit of (Rd, Rs, n) with ``theta_c_deg`` (or chosen per
    region, "auto"). A region whose highlight was not measured gets its diffuse colour only, with the
    reason; one never seen gets a diagnostics line. ``systematic``: each entry also gets the systematic
    uncertainty the rig file's own uncertainty gives it (``rd_sys``, …; :mod:`.systematic`; the robust
    estimator's). ``progress`` hears of each pose, region and systematic term; ``on_radiance`` of each
    pose's merged radiance and the pixels the fit took from it, as the pose is done.

    Returns
    -------
    FitResult
        Linear RGB reflectances with standard errors; n dimensionless (docs/formats.md,
        ``materials.json``).
    """
    rig, plan = session.rig, session.plan
    mesh = placed_mesh(session)
    caster = RayCaster(mesh)
    pooled: dict[int, _Pooled] = defaultdict(_Pooled)
    times = StageTimes()
    offsets: list[float] = []  # the black level's error each bracket implies (DN)
    alignment: list[PoseAlignment] = []  # is the object where the plan says, pose by pose
    for i, view in enumerate(session.views):
        progress(FitStep("poses", i, len(session.views), f"pose {view.pose}: HDR, geometry, selection"))
        with times("hdr"):
            radiance = view_radiance(session, view, mesh)
        offsets += [radiance.agreement[0].black_offset_dn] if radiance.agreement else []
        pose = view_pose(session, view)
        geometry = pose_geometry(plan, mesh, caster, rig.camera, pose, radiance.usable, times)
        samples = pose_samples(plan, mesh, caster, rig.camera, pose, radiance, selection, times, geometry)
        with times("alignment"):
            alignment.append(_alignment(session, view, geometry, radiance))
        for rid in np.unique(samples.region):
            pooled[int(rid)].add(i, view.pose, samples, samples.region == rid)
        if on_radiance is not None:
            used = np.zeros(radiance.usable.shape, bool)
            used[samples.pixel[:, 1], samples.pixel[:, 0]] = True
            on_radiance(PoseRadiance(view, pose, radiance, used))
    if pooled and not any(p.any_light() for p in pooled.values()):
        raise InputError(
            f"every pixel of the object is black in every frame of its {len(session.views)} pose(s): the lamp lit "
            f"nothing — {_DARK_ADVICE}",
            path=session.path,
        )

    entries: list[MaterialEntry] = []
    diagnostics: dict = {"format": DIAGNOSTICS_FORMAT, "version": 1, "regions": [],
                         "black_level": black_level_check(offsets, rig.file.sensor.black_level_dn),
                         "alignment": alignment_record(alignment, plan)}  # fmt: skip
    advice = misfit_advice(diagnostics["black_level"], diagnostics["alignment"])
    fits: dict[int, RegionFit] = {}
    responds: dict[int, Respond] = {}
    for i, region in enumerate(plan.object.regions):
        progress(FitStep("regions", i, len(plan.object.regions), f"region {region.id}: fitting"))
        p = pooled.get(region.id)
        if p is None:
            diagnostics["regions"].append(
                {"id": region.id, "samples": 0, "note": "not seen in any usable pixel"}
            )
            continue
        with times("fitting"):
            entry, diag, fit, respond = _fit_one(region, p, theta_c_deg, method, advice)
        if entry is not None:
            entries.append(entry)
            if respond is not None:
                responds[region.id] = respond
        diagnostics["regions"].append(diag)
        if fit is not None:
            fits[region.id] = fit
    if not entries:  # materials.json holds at least one region: say why there is none instead
        reasons = "; ".join(f"region {d['id']}: {d['note']}" for d in diagnostics["regions"][:4])
        raise InputError(
            f"no region could be fitted ({reasons}): the frames do not show the object lit as planned — check the "
            "lamp, the exposures and the rig file's [sensor] against the photographs",
            path=session.path,
        )
    record = None
    if systematic and responds:
        with times("systematic"):
            placement = plan.object.placement
            terms = [*rig_terms(rig, mesh.vertices), *placement_terms(placement, mesh.vertices.mean(axis=0)),
                     *lamp_terms(rig, watched=session.lamp.watched, warmed=session.lamp.warmed,
                                absolute=session.lamp.on_white_reference)]  # fmt: skip
            shifts = _systematic_shifts(session, caster, pooled, responds, terms, progress)
        entries = [_with_systematic(e, shifts.get(e.id), terms) for e in entries]
        record = _systematic_record(terms, shifts, diagnostics, method, placement_note(placement))
    fitted = {e.id for e in entries}
    notes = {d["id"]: d for d in diagnostics["regions"]}
    missing = [
        NotMeasured(id=r.id, color=list(r.color), vertices=r.vertices, samples=notes[r.id]["samples"],
                    reason=notes[r.id].get("note", "no entry"))
        for r in plan.object.regions if r.id not in fitted
    ]  # fmt: skip
    materials = materials_file(entries, mesh=plan.object.mesh, sha256=plan.object.sha256, systematic=record,
                               not_measured=missing)  # fmt: skip
    if session.gaps.missing_frames:  # fitted with --allow-incomplete: the file says on what
        materials = MaterialsFile.model_validate(
            {**materials.model_dump(exclude_none=True), "incomplete": session.gaps.as_record()}
        )
    return FitResult(materials, diagnostics, fits, dict(times))


def _alignment(session: Session, view: View, geometry: PixelGeometry, radiance: Radiance) -> PoseAlignment:
    """The pose's check of the object's placement (:mod:`.alignment`) on its own photograph."""
    sensor = session.rig.file.sensor
    longest = max(float(s["exposure_s"]) * 10 ** (float(s["gain_db"]) / 20) for s in view.sidecars.values())
    noise = sensor.read_noise_dn / (sensor.sensitivity * longest)
    cos_alpha = np.zeros(geometry.labels.shape)
    xs, ys = geometry.pixel[:, 0], geometry.pixel[:, 1]
    cos_alpha[ys, xs] = np.where(geometry.lit, geometry.cos_alpha, 0.0)
    return pose_alignment(view.pose, geometry.labels, cos_alpha, radiance.value, radiance.usable, noise)


def alignment_record(poses: list[PoseAlignment], plan: PlanFile) -> dict:
    """``fit-diagnostics.json``'s ``alignment``: each pose's check, the poses flagged and, when some are,
    what to do (docs/placement.md)."""
    flagged = [p.pose for p in poses if p.flagged]
    record: dict = {"poses": [p.as_record() for p in poses], "flagged": flagged,
                    "placement": plan.object.placement.status if plan.object.placement else "assumed"}  # fmt: skip
    if flagged:
        outline = max((p.outline.at_zero for p in poses if p.flagged and p.outline), default=0.0)
        record["warning"] = (
            f"the photographs of {len(flagged)} of {len(poses)} poses ({', '.join(flagged[:5])}) do not show the "
            f"placed mesh's outline and region borders where the plan puts them (outline off by {outline:.1f} px "
            "where the plan puts it; they fit better moved, or not at all): the object is not where the plan says "
            "— run hlr-lab register and acquire the placed plan; these materials are not to be trusted"
        )
    return record


def black_level_check(offsets: list[float], assumed_dn: float) -> dict:
    """What the brackets say of the rig file's black level: the median of the errors they imply (DN;
    :func:`~hlr_lab.reflectance.hdr.exposure_agreement`), over how many brackets, and a ``warning`` when it
    is further from 0 than ``BLACK_LEVEL_WARNING_DN`` (the dark regions' Rd and every Rs are then biased).
    Frames with dark frames subtracted cannot tell (their brackets imply 0)."""
    out: dict = {"rig_dn": assumed_dn, "brackets": len(offsets)}
    if not offsets:
        return out
    offset = float(np.median(offsets))
    out["offset_dn"] = round(offset, 2)
    if abs(offset) > BLACK_LEVEL_WARNING_DN:
        out["warning"] = (
            f"the exposure brackets put the sensor's black level {offset:+.1f} DN from the rig file's [sensor] "
            f"black_level_dn = {assumed_dn:g} (median of {len(offsets)} brackets): every pixel then reads that "
            "much too bright or dark, which biases the dark regions' Rd most; measure it (hlr-lab calibrate "
            "radiometric)"
        )
    return out


def _fit_one(
    region: RegionEntry, p: _Pooled, theta_c_deg, method: EstimatorName, advice: MisfitAdvice = MisfitAdvice()
) -> tuple[MaterialEntry | None, dict, RegionFit | None, Respond | None]:
    """The region's entry (None when not even its diffuse colour can be told), diagnostics, the fit when
    its specular was measured, and how the entry's numbers move with its inputs (None where they cannot
    be followed: no entry, or the paper's estimator). ``advice``: what a note on pixels that do not follow
    the model tells to check (:func:`misfit_advice`)."""
    intensity, irradiance, cos_alpha, cos_beta, footprint = p.inputs()
    diag = {"id": region.id, "samples": len(cos_beta), "samples_per_pose": p.per_view}
    unlit = _not_lit(intensity, irradiance, cos_alpha, cos_beta)
    if unlit:
        diag["note"] = unlit
        return None, diag, None, None
    patch = surface_patches(p.stacked("point"))
    try:
        fit = fit_region(intensity, irradiance, cos_alpha, cos_beta, theta_c_deg=theta_c_deg, method=method,
                         footprint=footprint, patch=patch)  # fmt: skip
    except (InsufficientSamples, DegenerateSamples) as exc:
        diag["specular"] = f"unmeasured: {exc}"
        entry, diag, respond = _diffuse_outcome(region, p, patch, str(exc), method, diag, advice)
        return entry, diag, None, respond
    held, below_black = _held_note(fit.held_at_zero, advice)
    if below_black:  # no near-black surface: pixels that do not follow the model get no entry
        diag["note"] = held
        return None, diag, None, None
    if held:
        diag["held_at_zero"] = held
    # a lobe no pixel saw: the nearest pixel lies beyond twice its half width (the fit then trades n for Rs
    # unchecked: measured n 2000 with Rs 1e13 on a region no highlight reached)
    nearest_deg = float(np.degrees(np.arccos(np.clip(cos_beta.max(), -1.0, 1.0))))
    half_width_deg = float(np.degrees(np.arccos(0.5 ** (1.0 / max(fit.n, 1e-9)))))
    if nearest_deg > 2 * half_width_deg:
        reason = (
            f"no highlight seen: the pixel nearest the mirror direction lies at β = {nearest_deg:.3g}°, beyond "
            f"the lobe's reach; plan a light whose highlight falls on this region"
        )
        diag["specular"] = f"unmeasured: {reason}"
        entry, diag, respond = _diffuse_outcome(region, p, patch, reason, method, diag, advice)
        return entry, diag, None, respond
    rs, rs_se = float(np.mean(fit.rs)), float(np.sqrt(np.mean(np.square(fit.rs_se))))
    if not rs > SIGNIFICANT * rs_se:  # the lobe was not seen: an Rs this close to 0 is not a measurement
        reason = (
            f"no significant highlight in {fit.n_highlight} pixels within θc = {fit.theta_c_deg:.3g}° "
            f"(Rs = {rs:.2g} ± {rs_se:.2g}); plan a light whose highlight falls on this region"
        )
        diag["specular"] = f"unmeasured: {reason}"
        # Rd as the full fit has it: with a lobe too faint to measure still in the model, its tail beyond
        # any β cone is not taken for diffuse light (Rd from β > 35° alone came out 0.8 % high, 9 σ, on a
        # faint n = 15 lobe), and Rd's standard error carries what the unmeasured lobe leaves uncertain
        wrong = _unphysical(fit.rd, advice=advice)  # materials.json cannot hold it
        if wrong:
            diag["note"] = wrong
            return None, diag, None, None
        pixels = PixelCounts(diffuse=fit.n_diffuse, highlight=fit.n_highlight)
        entry = unmeasured_entry(region, fit.rd, fit.rd_se, reason=reason, theta_c_deg=fit.theta_c_deg,
                                 pixels=pixels, residual_rms=fit.residual_rms, estimator=method)  # fmt: skip
        return entry, diag, None, _fit_response(fit, rd_only=True)
    diag["residual_rms"] = fit.residual_rms
    diag["beta_curve"] = _beta_curve(fit, intensity, irradiance, cos_alpha, cos_beta)
    # materials.json holds neither
    wrong = _unphysical(fit.rd, advice=advice) or _unphysical(fit.rs, "Rs", advice=advice)
    if wrong:
        diag["note"] = wrong
        return None, diag, None, None
    return measured_entry(region, fit), diag, fit, _fit_response(fit)


def _fit_response(fit: RegionFit, *, rd_only: bool = False) -> Respond | None:
    """How ``fit``'s numbers move with its inputs (``rd_only``: an entry that keeps only its Rd)."""
    if fit.response is None:
        return None

    def respond(moved: _Inputs) -> np.ndarray:
        shift = fit_shift(fit, *moved)
        if rd_only:
            shift[3:] = np.nan
        return shift

    return respond


def _diffuse_outcome(
    region: RegionEntry,
    p: _Pooled,
    patch: np.ndarray,
    reason: str,
    method: EstimatorName,
    diag: dict,
    advice: MisfitAdvice,
) -> tuple[MaterialEntry | None, dict, Respond | None]:
    """A region whose highlight was not measured: its diffuse colour from the pixels beyond the lobe's tail
    (``_diffuse_only``; ``patch`` (N,) each pixel's surface patch), or the note why there is none; and how
    that Rd moves with the inputs (the same pixels' least squares again)."""
    inputs = p.inputs()
    x = inputs.irradiance * inputs.cos_alpha
    cutoff = diffuse_cutoff(x, inputs.intensity, inputs.cos_beta, patch, MIN_DIFFUSE)
    entry = _diffuse_only(region, inputs, reason, method, patch, cutoff, advice)
    if isinstance(entry, str):
        diag["note"] = entry
        return None, diag, None
    if cutoff.note():
        diag["diffuse_cutoff"] = cutoff.note()
    far = inputs.cos_beta < np.cos(np.radians(cutoff.beta_deg))
    base = _diffuse_rd(inputs, far)

    def respond(moved: _Inputs) -> np.ndarray:
        return np.concatenate([_diffuse_rd(moved, far) - base, np.full(4, np.nan)])

    return entry, diag, respond


def surface_patches(points: np.ndarray) -> np.ndarray:
    """(N,) int: the patch of surface each of ``points`` (N, 3; turntable frame, m) lies in — cubes of
    ``PATCH_M`` — the same for every pose that sees it (the fit's standard errors count patches where the
    model's misses are shared by a patch's pixels: ``fitting.robust``)."""
    cells = np.floor(points / PATCH_M).astype(np.int64)
    return group_rows(cells)[0].astype(np.int64)  # np.unique(cells, axis=0)'s inverse; 15× faster on 2 M


def _diffuse_rd(inputs: _Inputs, far: np.ndarray) -> np.ndarray:
    """(3,) Rd by least squares over the pixels ``far`` (I = L·Rd·cos α), not held at 0."""
    return least_squares_rd(inputs.irradiance[far] * inputs.cos_alpha[far], inputs.intensity[far])


def _systematic_shifts(
    session: Session,
    caster: RayCaster,
    pooled: dict[int, _Pooled],
    responds: dict[int, Respond],
    terms: list[RigTerm],
    progress: Callable[[FitStep], None],
) -> dict[int, np.ndarray]:
    """Per region, (T, 7) how its (Rd[3], Rs[3], n) move under each of the T ``terms`` (NaN where the entry
    has no such number): its pixels held, their geometry and radiance taken again with the rig moved."""
    poses = [view_pose(session, v) for v in session.views]
    shifts: dict[int, np.ndarray] = {}
    for r, (rid, respond) in enumerate(responds.items()):  # a region at a time: one copy of its inputs
        progress(FitStep("systematic", r, len(responds), f"region {rid}: {len(terms)} terms of the rig"))
        fitted, rows = pooled[rid].inputs(), []
        for term in terms:
            if term.fraction is not None:  # a share of each value, not a move: _with_systematic takes it
                rows.append(np.full(7, np.nan))
                continue
            parts = [_moved_inputs(term, caster, session.rig, session.views[i], poses[i], part)
                     for i, part in pooled[rid].parts]  # fmt: skip
            moved = _Inputs(*(np.concatenate(c) for c in zip(*parts, strict=True)))
            # the derivative, not the move: Huber's ψ is linear only within the pixels' noise, which a whole
            # σ of the rig can exceed (10 % of the sensitivity is far beyond it): the inputs moved by a
            # thousandth of the term, the answer's move scaled back up
            nudged = _Inputs(*(a + _NUDGE * (b - a) for a, b in zip(fitted, moved, strict=True)))
            rows.append(respond(nudged) / _NUDGE)
        shifts[rid] = np.array(rows)
    return shifts


def _moved_inputs(
    term: RigTerm, caster: RayCaster, rig: Rig, view: View, pose: PoseGeometry, part: PoseSamples
) -> _Inputs:
    """One view's part of a region's inputs with the rig moved by ``term``: the same pixels, their light
    terms taken again, their radiance under the moved black level (the merge's own slope) or sensitivity."""
    intensity = part.intensity.astype(np.float64)
    irradiance, cos_alpha = part.irradiance.astype(np.float64), part.cos_alpha.astype(np.float64)
    cos_beta, nodes = part.cos_beta.astype(np.float64), part.footprint.nodes.astype(np.float64)
    if term.black_level_dn is not None:
        intensity = intensity + (term.black_level_dn - rig.file.sensor.black_level_dn) * part.black_slope
    if term.sensitivity_factor is not None:
        intensity = intensity / term.sensitivity_factor
    if term.camera is not None or term.kinematics is not None or term.object_moved is not None:
        moved_pose = pose
        if term.kinematics is not None:
            ticks = view.measured["gantry_ticks"]
            moved_pose = replace(
                pose,
                light_world=term.kinematics.light_position((ticks[0], ticks[1])),
                directional_from=None
                if pose.directional_from is None
                else np.asarray(term.kinematics.centre),
            )
        # the change, added to what the fit had (the same arithmetic either side: no rounding taken for a move)
        base = light_terms_again(caster, rig.camera, pose, part, recast=False)
        after = light_terms_again(caster, term.camera or rig.camera, moved_pose, part,
                                  recast=term.camera is not None or term.object_moved is not None,
                                  object_moved=term.object_moved)  # fmt: skip
        irradiance = irradiance + (after.irradiance - base.irradiance)
        cos_alpha = np.clip(cos_alpha + (after.cos_alpha - base.cos_alpha), 1e-6, 1.0)
        cos_beta = np.clip(cos_beta + (after.cos_beta - base.cos_beta), 1e-6, 1.0)
        nodes = np.minimum(nodes + (after.footprint - base.footprint), 0.0)
    return _Inputs(intensity, np.maximum(irradiance, 1e-300), cos_alpha, cos_beta, nodes)


def _with_systematic(entry: MaterialEntry, shifts: np.ndarray | None, terms: list[RigTerm]) -> MaterialEntry:
    """``entry`` with ``rd_sys`` (and ``rs_sys``, ``n_sys`` where measured): the terms' moves (T, 7) in
    quadrature, a term that is a share of each value (a device never calibrated) taken of the entry's
    own; ``shifts`` gets those rows filled in."""
    if shifts is None or len(shifts) == 0:
        return entry
    values = np.concatenate([entry.rd, entry.rs or [np.nan] * 3, [entry.n or np.nan]])
    for t, term in enumerate(terms):
        if term.fraction is not None:
            share = np.repeat([term.fraction["rd"], term.fraction["rs"], term.fraction["n"]], [3, 3, 1])
            shifts[t] = share * values
    sys = np.sqrt(np.sum(np.square(shifts), axis=0))
    update: dict = {"rd_sys": _listed(sys[:3])}
    if entry.specular == "measured" and np.all(np.isfinite(sys[3:])):
        update |= {"rs_sys": _listed(sys[3:6]), "n_sys": float(sys[6])}
    return entry.model_copy(update=update)


def _systematic_record(
    terms: list[RigTerm], shifts: dict[int, np.ndarray], diagnostics: dict, method, placement: str | None
) -> dict:
    """``materials.json``'s ``systematic``: how it was propagated and from what, and what of the placement
    it leaves out (``placement``); each region's moves per term go to the diagnostics, for a reader asking
    what dominates."""
    names = [f"{p} {c}" for p in ("Rd", "Rs") for c in "RGB"] + ["n"]
    for d in diagnostics["regions"]:
        moves = shifts.get(d["id"])
        if moves is None:
            continue
        rows = []
        for term, row in zip(terms, moves, strict=True):
            cells = {name: float(v) for name, v in zip(names, row, strict=True) if np.isfinite(v)}
            rows.append({"term": term.name, **cells})
        d["systematic"] = rows
    uncalibrated = sorted({t.device for t in terms if t.source == "uncalibrated"})
    record = {"method": "linearised", "terms": [t.as_record() for t in terms], "estimator": method}
    if placement:
        record["placement"] = placement
    if uncalibrated:
        record["uncalibrated"] = (
            f"no calibration record for the {', '.join(uncalibrated)}: the rig file's drawing was taken to be "
            "off by a conservative default (docs/fitting.md); calibrate (hlr-lab calibrate all) for figures that "
            "are the rig's own"
        )
    return record


def _listed(a: np.ndarray) -> list[float]:
    return [float(x) for x in a]


def _held_note(held_z: np.ndarray, advice: MisfitAdvice) -> tuple[str | None, bool]:
    """What the fit's channels held at 0 say (``held_z`` (6,): the unbounded values in standard errors,
    NaN where not held), or None; and whether an Rd channel went further below than a near-black
    surface's noise can take it (``BELOW_BLACK`` σ). Rs is not judged so: below 0 it says no highlight
    was seen in that channel, and its standard error, with n then undetermined, says nothing (measured:
    "−4e27 σ" on a region no highlight reached)."""
    names = [f"{p} {c}" for p in ("Rd", "Rs") for c in "RGB"]
    held = [(names[i], float(z)) for i, z in enumerate(held_z) if np.isfinite(z)]
    if not held:
        return None, False
    cells = ", ".join(f"{name} ({z:+.2g} σ)" for name, z in held)
    if min((z for name, z in held if name.startswith("Rd")), default=0.0) >= -BELOW_BLACK:
        return f"held at 0 where the unbounded fit went below it: {cells}", False
    return (f"the unbounded fit went below 0 by more than {BELOW_BLACK:g} σ: {cells} — these pixels do not "
            f"follow the model; {advice.below_black}", True)  # fmt: skip


def _not_lit(intensity, irradiance, cos_alpha, cos_beta) -> str | None:
    """Why a region's pixels (intensity (N, C), irradiance, cos α, cos β (N,)) cannot be a surface lit by
    the lamp, or None: all black, or not brightening where the light falls more directly (Pearson r of the
    mean channel with L·cos α below ``FOLLOWS_LIGHT``, over the pixels beyond the highlight cone, when there
    are enough of them and L·cos α varies enough to tell)."""
    if not np.any(intensity > 0):
        return (
            f"every one of its {len(intensity)} pixels is black in every frame: the lamp lit nothing "
            f"({_DARK_ADVICE})"
        )
    # only pixels outside the highlight can tell: inside it brightness follows β, not cos α (Spot's pupils,
    # seen only in their highlight, are anti-correlated with L·cos α, r = −0.96)
    far = cos_beta < np.cos(np.radians(DIFFUSE_BETA_DEG))
    x, y = irradiance[far] * cos_alpha[far], intensity[far].mean(axis=1)
    if len(x) < MIN_DIFFUSE or np.std(x) < SPREAD * np.mean(x):
        return None
    # a black surface cannot tell either: its pixels there are noise about 0, lit or not (its highlight,
    # if any, is the fit's to find); judged only where they stand clear of their own noise
    dx = x - x.mean()
    line = y.mean() + dx * (dx @ (y - y.mean())) / max(float(dx @ dx), 1e-300)
    if y.mean() < CLEAR_OF_NOISE * float(normal_mad(y - line)):
        return None
    r = float(np.corrcoef(x, y)[0, 1]) if np.std(y) > 0 else 0.0
    if r >= FOLLOWS_LIGHT:
        return None
    return (
        f"its {len(y)} pixels do not brighten where the lamp's light falls more directly (correlation r = "
        f"{r:.2f} with L·cos α; a lit surface gives nearly 1): the frames do not show this object lit by this "
        "lamp as the rig file places it — check the lamp, light from elsewhere (dark frames), the rig file's "
        "calibration (its [sensor] black level, camera and gantry: hlr-lab calibrate), and that the object "
        "photographed is the plan's, placed as planned"
    )


def _unphysical(values: np.ndarray, name: str = "Rd", *, advice: MisfitAdvice) -> str | None:
    """Why a fitted Rd or Rs (C,) cannot be a reflectance (a channel below 0, or above the 1.5
    materials.json allows), or None. The pixels then do not follow the model: most often a black level or a
    sensitivity × power that is not the rig's."""
    values = np.asarray(values)
    if np.all((values >= 0) & (values <= 1.5)):
        return None
    shown = ", ".join(f"{v:.3g}" for v in values)
    if np.any(values < 0):
        return f"the fit gave {name} = {shown} (below 0): {advice.below_black}"
    return f"the fit gave {name} = {shown} (above 1.5: more light than falls on it): {advice.too_bright}"


def _diffuse_only(
    region,
    inputs: _Inputs,
    reason: str,
    method: EstimatorName,
    patch: np.ndarray,
    cutoff: DiffuseCutoff,
    advice: MisfitAdvice,
) -> MaterialEntry | str:
    """Rd by least squares over the pixels beyond ``cutoff`` (I = L·Rd·cos α; ``fitting.diffuse_only``), with
    its SE — the pixels', or the surface patches' (``patch``, (N,) int) where that is the larger, as the full
    fit's —; or why there is none (too few such pixels, an Rd below 0)."""
    far = inputs.cos_beta < np.cos(np.radians(cutoff.beta_deg))
    x = inputs.irradiance[far] * inputs.cos_alpha[far]  # (M,)
    if len(x) < MIN_DIFFUSE:
        return f"no pixel beyond β = {cutoff.beta_deg:g}° either: no diffuse colour"
    y = inputs.intensity[far]  # (M, C)
    rd = least_squares_rd(x, y)
    rd_se = rd_standard_error(x, y - x[:, None] * rd, patch[far])
    if np.any(rd < -BELOW_BLACK * rd_se):
        shown = ", ".join(f"{v:.3g} ± {e:.1g}" for v, e in zip(rd, rd_se, strict=True))
        return f"the fit gave Rd = {shown}, below 0 by more than {BELOW_BLACK:g} σ: {advice.below_black}"
    # a near-black surface: a channel whose noise straddles 0 is held there (one parameter per channel:
    # the bounded least-squares solution is the clamped one)
    rd = np.maximum(rd, 0.0)
    wrong = _unphysical(rd, advice=advice)
    if wrong:
        return wrong
    resid = y - x[:, None] * rd
    tail = cutoff.note()
    return unmeasured_entry(
        region,
        rd,
        rd_se,
        reason=reason if tail is None else f"{reason}; {tail}",
        theta_c_deg=cutoff.beta_deg,
        pixels=PixelCounts(diffuse=int(far.sum()), highlight=0),
        residual_rms=float(np.sqrt((resid**2).mean())),
        estimator=method,
    )


def _beta_curve(fit: RegionFit, intensity, irradiance, cos_alpha, cos_beta, bins: int = 40) -> dict:
    """Mean specular part Is = I/L − Rd cos α (grey) in β bins up to 2 θc, with the fitted lobe."""
    beta = np.degrees(np.arccos(np.clip(cos_beta, 0, 1)))
    top = min(90.0, 2 * fit.theta_c_deg)
    edges = np.linspace(0.0, top, bins + 1)
    spec = (intensity / irradiance[:, None] - cos_alpha[:, None] * fit.rd).mean(axis=1)
    which = np.digitize(beta, edges) - 1
    inside = (which >= 0) & (which < bins)
    count = np.bincount(which[inside], minlength=bins)
    total = np.bincount(which[inside], weights=spec[inside], minlength=bins)
    centres = 0.5 * (edges[:-1] + edges[1:])
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / count, np.nan)
    lobe = float(np.mean(fit.rs)) * np.cos(np.radians(centres)) ** fit.n
    return {
        "beta_deg": centres.round(3).tolist(),
        "mean_is": [None if not np.isfinite(m) else float(m) for m in mean],
        "count": count.tolist(),
        "fitted_lobe": lobe.tolist(),
    }


def bracket_frame(session: Path, event: dict, sidecar: dict, dark: dict | None, rig: Rig) -> BracketFrame:
    """A journaled frame (and its dark frame) of ``session`` as the HDR merge takes it; :class:`InputError`
    naming the file when it is not a raw frame of ``rig``'s camera."""
    size = (rig.camera.width, rig.camera.height)
    pixels = load_frame(session, event, size)
    problem = _frame_problem(pixels, int(sidecar["bits"]), rig)
    dark_pixels = None if dark is None else load_frame(session, dark, size)
    if problem is None and dark_pixels is not None:
        problem = _frame_problem(dark_pixels, int(sidecar["bits"]), rig)
    if problem:
        raise InputError(
            f"{event['file']}: {problem}; it is not the frame this rig took — restore the session's frame, or "
            "delete it and its journal line is set aside when hlr-lab acquire runs on the session again",
            path=session,
        )
    return BracketFrame(
        pixels if pixels.ndim == 3 else pixels[..., None],
        float(sidecar["exposure_s"]),
        float(sidecar["gain_db"]),
        int(sidecar["bits"]),
        None if dark_pixels is None else _channels(dark_pixels),
    )


def _frame_problem(pixels: np.ndarray, bits: int, rig: Rig) -> str | None:
    """What makes an image (H, W[, C]) not a raw frame of ``rig``'s camera at ``bits`` bits, or None: its
    size, its channels, a container too small for its bits (an 8-bit image standing in for a 12-bit
    frame), values above the sensor's top code."""
    h, w = rig.camera.height, rig.camera.width
    if pixels.shape[:2] != (h, w):
        return f"it is {pixels.shape[1]}×{pixels.shape[0]} pixels, the rig's camera {w}×{h}"
    channels = pixels.shape[2] if pixels.ndim == 3 else 1
    if channels != 3:  # the fit's model is per RGB channel (a mono camera's frames cannot be fitted yet)
        return f"it has {channels} channel{'s' if channels > 1 else ''}, where hlr-lab fits RGB frames (3 channels)"
    if bits > 8 * pixels.dtype.itemsize:
        return f"it is a {8 * pixels.dtype.itemsize}-bit image, but its sidecar says the sensor gives {bits} bits"
    if int(pixels.max()) > (1 << bits) - 1:
        return f"it holds values up to {int(pixels.max())}, above a {bits}-bit sensor's {(1 << bits) - 1}"
    return None


def _channels(pixels: np.ndarray) -> np.ndarray:
    return pixels if pixels.ndim == 3 else pixels[..., None]
