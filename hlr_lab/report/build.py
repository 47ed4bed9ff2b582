"""Assemble the report of a fitted session: the plan, the materials with their standard errors, the β–Is
curves with the fitted lobes, each pose's photograph beside the fitted materials rendered back with an
error map and PSNR, and the run summary from the journal."""

from __future__ import annotations

import datetime as dt
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from hlr_lab import __version__
from hlr_lab.errors import InputError
from hlr_lab.files import atomic_write_text
from hlr_lab.formats.materials import MaterialsFile, read_materials
from hlr_lab.formats.planned_object import placement_line
from hlr_lab.object.raycast import RayCaster
from hlr_lab.reflectance.session_fit import (
    DIAGNOSTICS,
    MATERIALS,
    RADIANCE,
    Session,
    placed_mesh,
    view_pose,
    view_radiance,
    view_time,
)
from hlr_lab.reflectance.views import DEFAULT_SELECTION, pose_geometry
from hlr_lab.report import html as h
from hlr_lab.report.rerender import compare, rerender
from hlr_lab.session.journal import JOURNAL, read_journal

MAX_IMAGE_WIDTH = 330  # px per image in the page (three side by side)
CROP_MARGIN_PX = 12
# after the page loads, the body says how many images decoded (a headless browser's DOM dump shows it)
LOAD_CHECK = (
    "<script>addEventListener('load', () => { document.body.dataset.imagesLoaded ="
    " [...document.images].filter(i => i.complete && i.naturalWidth > 0).length; });</script>"
)


@dataclass
class ReportFigures:
    """The figures a report computes: the PSNR (dB) of each pose's re-render against its photograph."""

    psnr_db: dict[str, float] = field(default_factory=dict)  # per view (pose id)


def build_report(
    session: Session, progress=lambda _: None, page_folder: Path | None = None
) -> tuple[str, ReportFigures]:
    """The report page (self-contained HTML) of a fitted session, and its figures; ``progress`` is told
    each step. ``page_folder``: where the page will be written (default: the session), whence its links
    to the poses' radiance files (``fit --radiance``) are made."""
    materials_path = session.path / MATERIALS
    if not materials_path.is_file():
        raise InputError("no materials.json in the session: run hlr-lab fit on it first", path=session.path)
    materials = read_materials(materials_path)
    if materials.sha256 and materials.sha256 != session.plan.object.sha256:
        raise InputError(
            f"its materials are of another mesh ({materials.mesh}, sha256 {materials.sha256[:12]}…) than the "
            f"session's ({session.plan.object.mesh}): run hlr-lab fit on the session again",
            path=materials_path,
            field="sha256",
        )
    diagnostics_path = session.path / DIAGNOSTICS
    diagnostics = json.loads(diagnostics_path.read_text()) if diagnostics_path.is_file() else {"regions": []}
    figures = ReportFigures()
    poses_html = _poses(session, materials, figures, progress, page_folder or session.path)
    body = [
        f"<h1>hlr-lab report: {h.escape(session.path.name)}</h1>",
        _misplaced(diagnostics),
        _meta(session),
        "<h2>Materials</h2>",
        _materials(session, materials, diagnostics),
        "<h2>Highlights: β against the specular part, with the fitted lobe</h2>",
        _curves(diagnostics, {e.id for e in materials.regions if e.specular == "measured"}),
        "<h2>Photographs and the fitted materials rendered back</h2>",
        '<p class="note">Left: the captured bracket merged to linear radiance. Middle: the fitted materials '
        "rendered from the same geometry (measured turntable angle and lamp position, calibrated camera). "
        "Right: |difference|, black = 0, yellow = 10 % of the display white. PSNR over the object's pixels "
        "away from silhouettes, region borders and creases (where pixels mix surfaces), peak = the brightest "
        "captured value there.</p>",
        poses_html,
        "<h2>The lamp through the run</h2>",
        _lamp(session),
        "<h2>The plan</h2>",
        _plan(session),
        "<h2>Runs</h2>",
        _runs(session),
    ]
    page = (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
        f"<title>hlr-lab report: {h.escape(session.path.name)}</title><style>{h.STYLE}</style></head>"
        f"<body>{''.join(body)}{LOAD_CHECK}</body></html>"
    )
    return page, figures


def _misplaced(diagnostics: dict) -> str:
    """The fit's finding that the object is not where the plan says (fit-diagnostics.json's ``alignment``),
    at the top of the page: nothing below it is to be trusted; empty when the photographs fit."""
    warning = diagnostics.get("alignment", {}).get("warning")
    if not warning:
        return ""
    return f'<p class="misplaced"><strong>Misplaced object.</strong> {h.escape(warning)}</p>'


def _plan_source(session: Session) -> str:
    """Where the plan was when the session started, and the copy the session was read from."""
    first = session.record["plan"]["path"]
    try:
        kept = session.plan_path.relative_to(session.path)
    except ValueError:  # a session from before copies were kept: read from where it was
        return str(first)
    return f"{first} (read from the session's copy, {kept.as_posix()})"


def _meta(session: Session) -> str:
    started = dt.datetime.fromtimestamp(session.record.get("started_at", 0), dt.UTC).strftime(
        "%Y-%m-%d %H:%M UTC"
    )
    rows = [
        ["session", h.escape(session.path)],
        ["plan", h.escape(_plan_source(session))],
        ["object", h.escape(session.plan.object.mesh)],
        ["placement", h.escape(placement_line(session.plan))],
        ["rig", h.escape(session.rig.name)],
        ["started", started],
        ["report by", f"hlr-lab {h.escape(__version__)}"],
    ]
    return h.table(["", ""], rows, numeric_from=2)


def _lamp(session: Session) -> str:
    """The lamp's measured output over the run (acquire --lamp-every, or on the white reference beside the
    object) and what fitting without it would have cost: every pose's light off by its output's distance
    from 1, reflectances by as much."""
    lamp = session.lamp
    if len(lamp.times) == 0:
        return (
            '<p class="note">The run did not watch its lamp (acquire --lamp-every N, or a white reference '
            "beside the object): the fit took its power as the rig file says throughout.</p>"
        )
    if lamp.on_white_reference:  # absolute: against what the rig file says
        source, measured, unit = "the white reference by the object", "measurements on it", "the rig file's"
    else:  # relative to the session's first reference frame
        source, measured, unit = "the reference pose", "reference frames", "the first"
    minutes = (lamp.times - lamp.times[0]) / 60
    at_views = np.array([lamp.at(view_time(v)) for v in session.views])
    off = 100 * np.abs(at_views - 1)
    lo, hi = min(lamp.outputs.min(), 0.99), max(lamp.outputs.max(), 1.01)
    chart = h.scatter_svg(
        [(float(m), float(o), "") for m, o in zip(minutes, lamp.outputs, strict=True)],
        x_range=(0.0, float(max(minutes[-1], 1.0))),
        y_range=(float(lo), float(hi)),
        x_label="minutes since the first measurement",
        y_label=f"lamp output / {unit}",
        title=f"the lamp's output, from {source}",
        line=[(float(m), float(o)) for m, o in zip(minutes, lamp.outputs, strict=True)],
    )
    return (
        f'<div class="charts">{chart}</div><p>{len(lamp.times)} {measured}; the output ranged over '
        f"{lamp.outputs.min():.4f}–{lamp.outputs.max():.4f} of {unit}. The fit divided each pose's light by "
        f"the output at its time: without that, the poses' light would have been off by up to {off.max():.2f} % "
        f"(mean {off.mean():.2f} %), and the reflectances fitted under it with it.</p>"
    )


def _materials(session: Session, materials: MaterialsFile, diagnostics: dict) -> str:
    """The materials table, as materials.json has them, and each planned region without an entry with the
    fit's reason (fit-diagnostics.json)."""
    rows = []
    for e in materials.regions:
        rd = "<br>".join(
            _uncertain(v, s, y, 4) for v, s, y in zip(e.rd, e.rd_se, e.rd_sys or [None] * 3, strict=True)
        )
        if e.specular == "measured":
            assert e.rs is not None  # materials.json's model: a measured lobe has rs, rs_se, n, n_se
            assert e.rs_se is not None
            assert e.n is not None
            assert e.n_se is not None
            rs = "<br>".join(
                _uncertain(v, s, y, 4) for v, s, y in zip(e.rs, e.rs_se, e.rs_sys or [None] * 3, strict=True)
            )
            n = _uncertain(e.n, e.n_se, e.n_sys, 2)
        else:
            rs, n = f"unmeasured: {h.escape(e.reason)}", "—"
        # an unmeasured lobe has no θc (its entry's is the cone in which a highlight was looked for)
        theta = f"{e.theta_c_deg:.1f}°" if e.specular == "measured" else "—"
        rows.append(
            [
                f"{e.id} {h.swatch(e.color)}",
                rd,
                rs,
                n,
                theta,
                f"{e.pixels.diffuse} / {e.pixels.highlight}",
                f"{e.residual_rms:.3g}",
            ]
        )
    entries = {e.id for e in materials.regions}
    # why a region has no entry: materials.json's own word (older files: the diagnostics')
    why = {d["id"]: d.get("note", "") for d in diagnostics.get("regions", [])}
    why |= {r.id: f"{r.reason} ({r.samples} usable pixels)" for r in materials.not_measured}
    missing = [
        f"region {r.id}: {h.escape(why.get(r.id) or 'not fitted (no diagnostics)')}"
        for r in session.plan.object.regions
        if r.id not in entries
    ]
    note = f'<p class="note">Regions without an entry: {"; ".join(missing)}.</p>' if missing else ""
    headers = ["region", "Rd (linear)", "Rs", "n", "θc", "pixels diffuse / highlight", "residual RMS"]
    return h.table(headers, rows) + _uncertainty_note(materials) + note


def _uncertain(v: float, se: float, sys: float | None, digits: int) -> str:
    """A value ± its statistical standard error, and ± its systematic one where the fit propagated it."""
    return f"{v:.{digits}f} ± {se:.{digits}f}" + ("" if sys is None else f" ± {sys:.{digits}f}")


def _uncertainty_note(materials: MaterialsFile) -> str:
    """What the ± in the table are, and what the systematic part came from (materials.json's record)."""
    record = materials.systematic
    if record is None:
        return (
            '<p class="note">± the statistical standard error (the pixels\' noise); no systematic part.</p>'
        )
    sources = sorted({t.source for t in record.terms})
    text = (
        "Each value ± its statistical standard error (the pixels' noise) ± its systematic one: what the rig file's "
        f"own uncertainty leaves uncertain ({len(record.terms)} independent terms, {', '.join(sources)}; "
        "propagated to first order — docs/fitting.md). Combined: the square root of the sum of their squares."
    )
    for left_out in (record.uncalibrated, record.placement):
        if left_out:
            text += f" <b>{h.escape(left_out)}.</b>"
    # the one term a user can remove at the rig: the lamp's level, where nothing measured it absolutely
    for lamp in (t for t in record.terms if t.source == "lamp record"):
        text += (
            f" The {h.escape(lamp.name)}: {h.escape(lamp.size)} of sensitivity × power, from what the "
            "radiometric calibration saw of the lamp; a white reference beside the object measures it in "
            'every pose (docs/sessions.md, "The lamp").'
        )
    return f'<p class="note">{text}</p>'


def _curves(diagnostics: dict, measured: set[int]) -> str:
    """The β–Is curve of each region whose lobe materials.json holds as measured."""
    charts = []
    for d in diagnostics.get("regions", []):
        curve = d.get("beta_curve")
        if not curve or d["id"] not in measured:
            continue
        beta, mean, lobe = curve["beta_deg"], curve["mean_is"], curve["fitted_lobe"]
        points = [(b, m, "") for b, m in zip(beta, mean, strict=True) if m is not None]
        top = max([m for _, m, _ in points] + lobe + [1e-9])
        bottom = min([0.0] + [m for _, m, _ in points])
        bottom = 0.0 if bottom > -0.02 * top else bottom  # noise about zero: keep the axis at 0
        charts.append(
            h.scatter_svg(
                points,
                x_range=(0.0, max(beta[-1], 1.0)),
                y_range=(bottom, top * 1.05),
                x_label="β (degrees)",
                y_label="Is = I/L − Rd cos α",
                title=f"region {d['id']}",
                line=list(zip(beta, lobe, strict=True)),
            )
        )
    return (
        f'<div class="charts">{"".join(charts)}</div>'
        if charts
        else '<p class="note">No measured highlights.</p>'
    )


def _poses(
    session: Session, materials: MaterialsFile, figures: ReportFigures, progress, page_folder: Path
) -> str:
    mesh = placed_mesh(session)
    caster = RayCaster(mesh)
    rows = []
    for i, view in enumerate(session.views):
        progress(f"pose {view.pose} ({i + 1}/{len(session.views)}): rendering the fit back")
        radiance = view_radiance(session, view, mesh)
        pose = view_pose(session, view)
        geometry = pose_geometry(session.plan, mesh, caster, session.rig.camera, pose, radiance.usable)
        rendered = rerender(geometry, materials, radiance.value.shape)
        # compared where the fit's samples come from: pixels that mix surfaces (at silhouettes, region
        # borders, creases) are not described by pixel-centre geometry
        interior = np.zeros(radiance.usable.shape, bool)
        interior[geometry.pixel[:, 1], geometry.pixel[:, 0]] = geometry.interior(DEFAULT_SELECTION.border_px)
        c = compare(radiance.value, rendered, interior)
        figures.psnr_db[view.pose] = c.psnr_db
        if not c.mask.any():
            rows.append(f"<p>{h.escape(view.pose)}: no object pixel with usable radiance.</p>")
            continue
        white = float(np.percentile(radiance.value[c.mask], 99.5))
        crop = _crop(c.mask)
        images = [
            h.tone_map(radiance.value[crop], white),
            h.tone_map(np.where(c.mask[..., None], rendered, 0.0)[crop], white),
            h.error_map(radiance.value[crop], rendered[crop], c.mask[crop], 0.1 * white),
        ]
        images = [_fit_width(im) for im in images]
        captions = [f"{view.pose}: captured", "fitted materials rendered", f"error (PSNR {c.psnr_db:.1f} dB)"]
        rows.append(
            "<div>" + "".join(h.figure(im, cap) for im, cap in zip(images, captions, strict=True)) + "</div>"
        )
        exr = session.path / RADIANCE / f"{view.pose}.exr"
        if exr.is_file():  # fit --radiance wrote it
            link = Path(os.path.relpath(exr, page_folder)).as_posix()
            rows.append(f'<p class="note">{h.escape(view.pose)}: linear radiance, masks and the pose in the header: '
                        f'<a href="{h.escape(link)}">{h.escape(link)}</a> (OpenEXR)</p>')  # fmt: skip
    return "".join(rows)


def _crop(mask: np.ndarray) -> tuple[slice, slice]:
    ys, xs = np.nonzero(mask)
    y0, y1 = max(ys.min() - CROP_MARGIN_PX, 0), min(ys.max() + CROP_MARGIN_PX + 1, mask.shape[0])
    x0, x1 = max(xs.min() - CROP_MARGIN_PX, 0), min(xs.max() + CROP_MARGIN_PX + 1, mask.shape[1])
    return slice(y0, y1), slice(x0, x1)


def _fit_width(rgb: np.ndarray) -> np.ndarray:
    if rgb.shape[1] <= MAX_IMAGE_WIDTH:
        return rgb
    height = round(rgb.shape[0] * MAX_IMAGE_WIDTH / rgb.shape[1])
    return cv2.resize(rgb, (MAX_IMAGE_WIDTH, height), interpolation=cv2.INTER_AREA)


def _plan(session: Session) -> str:
    plan = session.plan
    points = [(p.light.azimuth_deg, p.light.elevation_deg, p.id) for p in plan.poses]
    chart = h.scatter_svg(
        points,
        x_range=(-180.0, 180.0),
        y_range=(-10.0, 90.0),
        x_label="azimuth (degrees)",
        y_label="elevation (degrees)",
        title="planned light positions on the sphere (turntable frame)",
        size=(560, 260),
    )
    rows = [
        [
            h.escape(p.id),
            f"{p.turntable_deg:g}°",
            f"{p.light.azimuth_deg:.1f}°",
            f"{p.light.elevation_deg:.1f}°",
            h.escape(
                ", ".join(f"{k}: {v}" for k, v in sorted(p.expected.items(), key=lambda kv: int(kv[0])))
            ),
        ]
        for p in plan.poses
    ]
    return chart + h.table(["pose", "turntable", "azimuth", "elevation", "expected samples by region"], rows)


def _runs(session: Session) -> str:
    events = read_journal(session.path / JOURNAL)
    rows = []
    for e in events:
        if e.get("event") in ("run_end", "stopped"):
            when = dt.datetime.fromtimestamp(e["at"], dt.UTC).strftime("%Y-%m-%d %H:%M:%S")
            outcome = "finished" if e["event"] == "run_end" else f"stopped: {h.escape(e.get('reason', ''))}"
            rows.append(
                [
                    when,
                    outcome,
                    str(e.get("frames_taken", e.get("taken", "?"))),
                    str(e.get("poses_moved", "?")),
                    str(e.get("retries", "?")),
                    f"{e.get('duration_s', float('nan')):.1f} s",
                ]
            )
    retries = [e for e in events if e.get("event") == "retry"]
    listing = "".join(f"<li>{h.escape(e.get('pose'))}: {h.escape(e.get('error'))}</li>" for e in retries[:50])
    more = (
        f"<p>Retries ({len(retries)}):</p><ul>{listing}</ul>"
        if retries
        else "<p>No device exchange was retried.</p>"
    )
    return (
        h.table(["ended", "outcome", "frames taken", "poses moved to", "retries", "duration"], rows, 2) + more
    )


def write_report(path: Path, page: str) -> None:
    """Write the report ``page`` to ``path`` atomically."""
    atomic_write_text(path, page)
