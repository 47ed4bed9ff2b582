"""What ``hlr-lab register`` (and ``acquire --register``) show of a registration: where the object lies
against where the plan assumed it, how certain that is, and what was written."""

from __future__ import annotations

from rich.markup import escape

from hlr_lab.registration import Registered


def registration_lines(done: Registered) -> list[str]:
    """Rich-markup lines: the offset and its standard errors, the outline's residual, ambiguity, the files."""
    r = done.record
    shift = r.offset_shift_mm or [0.0, 0.0, 0.0]
    se_shift = r.se_shift_mm or [0.0, 0.0, 0.0]
    se_rot = r.se_rotation_deg or [0.0, 0.0, 0.0]
    lines = [
        f"the object lies {shift[0]:+.2f} ± {se_shift[0]:.2f}, {shift[1]:+.2f} ± {se_shift[1]:.2f}, "
        f"{shift[2]:+.2f} ± {se_shift[2]:.2f} mm from where the plan put it, turned {r.offset_turn_deg:+.2f}° "
        f"(± {se_rot[2]:.2f}°) about the axis, tilted {r.offset_tilt_deg:.2f}°",
        f"outline: {r.residual_px:.2f} px RMS, {100 * (r.outline_seen or 0):.1f} % of it found on the photographs, "
        f"{r.outline_offset_px or 0.0:+.2f} px outside the mesh's all round; "
        f"the turn from the {done.measured.found.turn_from}",
    ]
    if done.measured.face is not None:
        lines.append(f"[bold yellow]{escape(done.measured.face)}[/]: planned again for it")
    if r.status == "ambiguous":
        lines.append(f"[bold yellow]ambiguous:[/] {escape(r.why or '')} — written, and marked so in the plan")
    seconds = ", ".join(f"{k} {v:.0f} s" for k, v in done.seconds.items())
    lines.append(f"photographs in {escape(str(done.folder))} ({seconds})")
    if done.summary is not None:
        lines.append(f"summary: {escape(str(done.summary))}")
    if done.summary_problem is not None:
        lines.append(f"[yellow]{escape(done.summary_problem)}[/]")
    lights = len(done.plan.poses)
    lines.append(f"wrote {escape(str(done.output))}: planned again for where it lies, {lights} lights")
    if done.uncovered:
        lines.append(
            f"[yellow]regions {', '.join(map(str, done.uncovered))} no longer get their samples where the object "
            "lies: move it nearer the centre, or accept the shortfall[/]"
        )
    return lines
