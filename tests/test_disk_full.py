"""A full disk: refused before a run when the forecast does not fit; mid-run, one line naming the file
and the free space, the rig safe and the journal's last line written all the same; ``fit`` likewise.

The small disk is a tmpfs mounted for the test, which needs root (CI runs as root; elsewhere these
tests are skipped, and fail in CI rather than skip)."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from hlr_lab.cli.main import main
from hlr_lab.errors import DiskFull
from hlr_lab.formats.plan import read_plan
from hlr_lab.session.journal import JOURNAL, read_journal
from tests.films import resume_command
from tests.test_acquisition import run, world_of


def fill(disk: Path, leave_bytes: int) -> None:
    """A ballast file that leaves about ``leave_bytes`` free on ``disk`` (or none: others write too)."""
    with open(disk / "ballast", "ab") as f:
        try:
            while (free := shutil.disk_usage(disk).free) > leave_bytes:
                f.write(b"\1" * min(65536, max(free - leave_bytes, 4096)))
                f.flush()
        except OSError:
            pass


def test_a_disk_that_fills_mid_run_stops_it_with_one_line_and_the_rig_safe(plan_file, rig, small_disk):
    """The disk fills while the rig moves to the second pose: the run stops with DiskFull naming the frame
    file and the free space; the journal's last line (written into the room kept for it) says so and
    counts only the frames that were stored; lamp off, no torque."""
    disk = small_disk(24)
    plan = read_plan(plan_file[0])
    plan = plan.model_copy(update={"poses": plan.poses[:2]})
    session = disk / "session"

    def progress(step):
        if (step.index, step.action) == (1, "moving"):
            fill(disk, leave_bytes=0)  # not even the journal's last line fits: it uses the room kept for it

    with world_of(plan_file) as world:
        with pytest.raises(DiskFull, match=r"(\.png|journal\.jsonl): no space left on the device .* MB free"):
            run(world, rig, plan, session, progress=progress)
        assert not world.turntable.stage.lamp
        assert all(s.get("torque_enable") == 0 for s in world.bus.servos)
    events = read_journal(session / JOURNAL)
    assert events[-1]["event"] == "stopped"
    assert "no space left" in events[-1]["reason"]
    assert events[-1]["frames_taken"] == sum(e["event"] == "frame" for e in events)
    assert not list((session / "frames").glob(".*.tmp"))


def test_a_run_that_cannot_fit_is_refused_before_anything_moves(builtin_plan, small_disk, capsys):
    disk = small_disk(40)
    session = disk / "session"
    assert main(["acquire", "--plan", str(builtin_plan), "--sim", "--out", str(session)]) == 1
    err = capsys.readouterr().err
    assert re.search(r"need up to [\d,]+ MB \(6 frames of up to 7\.4 MB .*\), but \d+ MB is free", err), err
    assert not session.exists()


def test_fit_on_a_full_disk_is_one_line_and_leaves_nothing_half_written(finished_session, small_disk, capsys):
    disk = small_disk(32)
    session = disk / "session"
    shutil.copytree(finished_session, session)
    fill(disk, leave_bytes=0)
    assert main(["fit", str(session)]) == 1
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith(("error", "internal"))]
    assert len(lines) == 1, err
    assert re.match(r"error: .*materials.json: no space left on the device", lines[0]) or re.match(
        r"error: .*fit-diagnostics.json: no space left on the device", lines[0]
    ), err
    assert not list(session.glob(".*.tmp"))


def test_a_resumed_run_removes_the_temporaries_of_a_killed_one(
    finished_session, builtin_plan, quarter_rig, tmp_path, capsys
):
    session = tmp_path / "session"
    shutil.copytree(finished_session, session)
    leftovers = [session / "frames" / ".p000_e0.png.k3j2.tmp", session / ".session.json.x1.tmp"]
    for p in leftovers:
        p.write_bytes(b"\0" * 1000)
    before = [e for e in read_journal(session / JOURNAL) if e["event"] == "frame"]
    assert main(resume_command(builtin_plan, quarter_rig, session)) == 0
    assert not any(p.exists() for p in leftovers)
    assert [e for e in read_journal(session / JOURNAL) if e["event"] == "frame"] == before
    capsys.readouterr()


def test_a_read_only_output_folder_is_one_line_not_an_internal_error(
    small_disk, finished_session, tmp_path, capsys
):
    """segment, plan, fit and export into a read-only folder (a read-only tmpfs: root ignores file modes):
    each one `error:` line naming the file and saying what to do, exit status 1."""
    locked = small_disk(1, read_only=True)
    session = finished_session
    assert main(["fit", str(session), "-o", str(tmp_path / "materials.json")]) == 0
    for command in (
        ["segment", "--mesh", "builtin:pebble", "-o", str(locked / "regions.json")],
        ["plan", "--mesh", "builtin:pebble", "--sim", "-o", str(locked / "plan.json")],
        ["fit", str(session), "-o", str(locked / "materials.json")],
        ["export", str(tmp_path / "materials.json"), "--mesh", "builtin:pebble", "--format", "obj", "-o",
         str(locked / "o.obj")],
    ):  # fmt: skip
        assert main(command) == 1, command
        err = capsys.readouterr().err
        assert "internal error" not in err
        assert re.search(rf"error: {re.escape(str(locked))}/[^:]*: .*read-only", err), err


def test_files_written_together_are_written_all_or_none(finished_session, small_disk, tmp_path, capsys):
    """A disk with room for the first files of a set but not the rest (tmpfs counts 4 KB pages): 8 KB free
    holds materials.json (~3 KB) or an .mtl, not the diagnostics (~13 KB) or the OBJ (1.6 MB); 400 KB holds
    two of the Mitsuba scene's PLYs (177 KB each), not the third. fit and export write none of their files
    and leave no temporary."""
    materials = tmp_path / "materials.json"
    assert main(["fit", str(finished_session), "-o", str(materials)]) == 0
    export = ["export", str(materials), "--mesh", "builtin:pebble", "--format"]
    for free_kb, command in (
        (8, ["fit", str(finished_session), "-o", "materials.json"]),
        (8, [*export, "obj", "-o", "o.obj"]),
        (400, [*export, "mitsuba", "-o", "scene"]),
    ):
        disk = small_disk(1)
        fill(disk, leave_bytes=free_kb * 1024)
        capsys.readouterr()
        assert main([*command[:-1], str(disk / command[-1])]) == 1, command
        err = capsys.readouterr().err
        assert re.search(r"error: .*: no space left on the device", err), err
        assert sorted(p.name for p in disk.rglob("*") if p.is_file()) == ["ballast"], command
