"""A session folder cannot be turned against its user (issue 20). §1: a symbolic link or a special file
where a session is written or read is refused naming it, and nothing outside the session is written,
truncated or deleted; each case is a finished session (or a new one) with one name replaced by a link to
a victim outside. §2: fit and report refuse an output over the session's own files or their inputs, before
they work. Each would write through the link or over the file without the checks (tried on the code before
them)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hlr_lab.cli.main import main
from tests.films import resume_command

pytestmark = pytest.mark.renderer  # a resumed run starts the simulated rig before it is refused

VICTIM = b"the user's own file: not hlr-lab's\n"


def _victim(tmp_path: Path) -> Path:
    victim = tmp_path / "outside" / "victim.txt"
    victim.parent.mkdir()
    victim.write_bytes(VICTIM)
    return victim


@pytest.mark.parametrize(
    "name",
    ["journal.reserve", "acquire.lock", "acquire.log", "journal.damaged", "journal.jsonl", "session.json"],
)
def test_a_link_in_place_of_a_session_file_is_refused_and_its_target_untouched(
    name, finished_session, builtin_plan, quarter_rig, tmp_path, capsys
):
    session = tmp_path / "session"
    shutil.copytree(finished_session, session)
    victim = _victim(tmp_path)
    if name == "journal.damaged":  # a garbage line makes a resumed run set it aside into journal.damaged
        with (session / "journal.jsonl").open("a") as f:
            f.write("}}not json\n")
    (session / name).unlink(missing_ok=True)
    (session / name).symlink_to(victim)
    assert main(resume_command(builtin_plan, quarter_rig, session, speed_factor=200)) == 1
    err = capsys.readouterr().err
    assert f"{session / name}: is a symbolic link" in " ".join(err.split())
    assert "internal error" not in err
    assert victim.read_bytes() == VICTIM
    assert sorted(p.name for p in victim.parent.iterdir()) == ["victim.txt"]


@pytest.mark.parametrize("folder", ["frames", "object"])
def test_a_session_folder_that_is_a_link_is_refused_and_nothing_outside_is_written_or_deleted(
    folder, finished_session, builtin_plan, quarter_rig, tmp_path, capsys
):
    session = tmp_path / "session"
    shutil.copytree(finished_session, session)
    elsewhere = tmp_path / "elsewhere"
    shutil.move(session / folder, elsewhere)  # the folder's files, moved out of the session
    (elsewhere / ".p000_e0.png.abcd.tmp").write_bytes(VICTIM)  # a run's temporaries there would be removed
    before = {p.name: p.read_bytes() for p in elsewhere.iterdir() if p.is_file()}
    (session / folder).symlink_to(elsewhere, target_is_directory=True)
    for command in (
        resume_command(builtin_plan, quarter_rig, session, speed_factor=200),
        ["fit", str(session)],
        ["report", str(session)],
    ):
        assert main(command) == 1
        err = " ".join(capsys.readouterr().err.split())
        assert f"{session / folder}: is a symbolic link" in err, err
    assert {p.name: p.read_bytes() for p in elsewhere.iterdir() if p.is_file()} == before
    assert not (session / "materials.json").exists()


def test_a_new_session_with_a_linked_frames_folder_is_refused_before_anything_is_written(
    builtin_plan, quarter_rig, tmp_path, capsys
):
    session, elsewhere = tmp_path / "new", tmp_path / "elsewhere"
    session.mkdir()
    elsewhere.mkdir()
    (session / "frames").symlink_to(elsewhere, target_is_directory=True)
    assert main(resume_command(builtin_plan, quarter_rig, session, speed_factor=200)) == 1
    assert f"{session / 'frames'}: is a symbolic link" in " ".join(capsys.readouterr().err.split())
    assert list(elsewhere.iterdir()) == []
    assert sorted(p.name for p in session.iterdir()) == ["frames"]  # not even a lock or a journal


def test_a_new_session_is_not_started_among_someone_elses_files_but_a_run_stopped_before_it_resumes(
    builtin_plan, quarter_rig, tmp_path, capsys
):
    """``--out ~/thesis``: a folder that is not a session (no session.json, no journal) and holds other
    files is refused naming them, before anything is written there; one that holds only a session's own
    files (a run that stopped before its session.json) is a session to start."""
    session = tmp_path / "thesis"
    session.mkdir()
    (session / "thesis.tex").write_bytes(VICTIM)
    assert main(resume_command(builtin_plan, quarter_rig, session, speed_factor=200)) == 1
    said = " ".join(capsys.readouterr().err.split())
    assert f"{session}: is not a session and holds other files (thesis.tex)" in said, said
    assert "give a new --out" in said
    assert sorted(p.name for p in session.iterdir()) == ["thesis.tex"]  # not even a lock
    stopped = tmp_path / "stopped"
    stopped.mkdir()
    (stopped / "acquire.lock").write_bytes(b"")
    (stopped / "acquire.log").write_bytes(b"")
    assert main(resume_command(builtin_plan, quarter_rig, stopped, speed_factor=200)) == 0
    assert (stopped / "session.json").is_file()


@pytest.mark.timeout(120)  # a FIFO read would block forever; /dev/zero would fill the memory
@pytest.mark.parametrize("special", ["fifo", "/dev/zero"])
def test_a_journal_that_is_a_fifo_or_a_device_is_refused_at_once(special, finished_session, tmp_path, capsys):
    session = tmp_path / "session"
    shutil.copytree(finished_session, session)
    journal = session / "journal.jsonl"
    journal.unlink()
    if special == "fifo":
        os.mkfifo(journal)
        said = "is not a regular file or folder (a FIFO, a socket or a device)"
    else:
        journal.symlink_to(special)
        said = "is a symbolic link"
    assert main(["fit", str(session)]) == 1
    assert f"{journal}: {said}" in " ".join(capsys.readouterr().err.split())


def test_an_output_that_is_a_link_is_refused_and_its_target_kept(finished_session, tmp_path, capsys):
    session = tmp_path / "session"
    shutil.copytree(finished_session, session)
    victim = _victim(tmp_path)
    link = tmp_path / "materials-link.json"
    link.symlink_to(victim)
    assert main(["fit", str(session), "-o", str(link)]) == 1
    assert f"{link}: --output: is a symbolic link" in " ".join(capsys.readouterr().err.split())
    assert victim.read_bytes() == VICTIM
    assert link.is_symlink()


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {
        p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def test_fit_refuses_an_output_over_the_sessions_own_files(finished_session, tmp_path, capsys):
    session = tmp_path / "session"
    shutil.copytree(finished_session, session)
    frame = sorted((session / "frames").glob("*.png"))[0].relative_to(session).as_posix()
    before = _snapshot(session)
    for name in ("journal.jsonl", "session.json", "object/plan.json", frame):
        assert main(["fit", str(session), "-o", str(session / name)]) == 1
        err = " ".join(capsys.readouterr().err.split())
        assert f"{session / name}: --output: is one of the session" in err, err
    out = tmp_path / "out"
    assert (
        main(["fit", str(session), "-o", str(out / "fit-diagnostics.json")]) == 1
    )  # over its own diagnostics
    assert "written twice" in " ".join(capsys.readouterr().err.split())
    assert _snapshot(session) == before
    assert not out.exists()


def test_report_refuses_an_output_over_the_session_or_the_materials_it_reads(
    finished_session, tmp_path, capsys
):
    session = tmp_path / "session"
    shutil.copytree(finished_session, session)
    assert main(["fit", str(session)]) == 0
    capsys.readouterr()
    before = _snapshot(session)
    for name, said in (("journal.jsonl", "is one of the session"), ("materials.json", "is also this command's input"),
                       ("fit-diagnostics.json", "is also this command's input")):  # fmt: skip
        assert main(["report", str(session), "-o", str(session / name)]) == 1
        err = " ".join(capsys.readouterr().err.split())
        assert f"{session / name}: --output: {said}" in err, err
    assert _snapshot(session) == before


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_entry_of_a_session_replaced_by_a_link_or_a_special_file_is_refused_naming_it(
    data, finished_session, tmp_path_factory, capsys
):
    """Property (issue 20): whichever file or folder of a finished session becomes a link (to a file
    outside, to /dev/zero) or a FIFO, fit and report refuse it naming that entry, read nothing through
    it and write nothing outside; the victim keeps its bytes."""
    root = tmp_path_factory.mktemp("hostile")
    session = root / "session"
    shutil.copytree(finished_session, session)
    entries = sorted(p.relative_to(session).as_posix() for p in session.rglob("*"))
    name = data.draw(st.sampled_from(entries), label="entry")
    kind = data.draw(st.sampled_from(["link to a file outside", "link to /dev/zero", "fifo"]), label="kind")
    victim = root / "victim.txt"
    victim.write_bytes(VICTIM)
    target = session / name
    shutil.rmtree(target) if target.is_dir() else target.unlink()
    if kind == "fifo":
        os.mkfifo(target)
    else:
        target.symlink_to(victim if kind == "link to a file outside" else Path("/dev/zero"))
    for command in (["fit", str(session)], ["report", str(session)]):
        capsys.readouterr()
        assert main(command) == 1
        err = " ".join(capsys.readouterr().err.split())
        assert f"{target}: is " in err, (name, kind, err)
        assert "internal error" not in err
    assert victim.read_bytes() == VICTIM
    assert sorted(p.name for p in root.iterdir()) == ["session", "victim.txt"]
