"""The session directory: frames stored bit for bit and never replaced, a journal that survives a kill."""

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from hlr_lab.errors import InputError
from hlr_lab.files import FILE_MODE
from hlr_lab.session.frames import frame_problem, load_frame, store_frame
from hlr_lab.session.journal import DAMAGED, Journal, load_journal, read_journal
from hlr_lab.session.metadata import SESSION, start_or_resume
from hlr_lab.session.writer import FrameWriter


def frame_fields(pose: str = "p000", k: int = 0, exposure_s: float = 0.01) -> dict:
    """What a journal frame line and its sidecar both say about a frame (as acquisition writes them)."""
    return {"pose": pose, "exposure_index": k, "dark": False, "exposure_s": exposure_s}


def stored_event(session, name, pixels, **fields) -> dict:
    """A frame stored and described as acquisition does: the journal line for it."""
    f = frame_fields(**fields)
    stored = store_frame(session, name, pixels, f)
    return {"event": "frame", **f, "adaptive": False, "clipped_pixels": 0, **stored.files()}


@pytest.mark.parametrize(
    ("shape", "dtype", "top"), [((48, 64, 3), np.uint16, 4095), ((48, 64), np.uint8, 255)]
)
def test_frames_are_stored_bit_for_bit(tmp_path, shape, dtype, top):
    pixels = np.random.default_rng(0).integers(0, top + 1, size=shape).astype(dtype)
    event = stored_event(tmp_path, "p000_e0", pixels)
    assert frame_problem(tmp_path, event) is None
    back = load_frame(tmp_path, event)
    assert back.dtype == dtype
    np.testing.assert_array_equal(back, pixels)  # RGB order kept: OpenCV's BGR stays inside


def test_nothing_is_overwritten(tmp_path):
    first = np.full((4, 4, 3), 7, np.uint16)
    event = stored_event(tmp_path, "p000_e0", first)
    with pytest.raises(FileExistsError):
        store_frame(tmp_path, "p000_e0", first + 1, {})
    np.testing.assert_array_equal(load_frame(tmp_path, event), first)
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == ["p000_e0.json", "p000_e0.png"]


def test_a_changed_or_missing_frame_is_detected(tmp_path):
    event = stored_event(tmp_path, "a", np.zeros((4, 4, 3), np.uint16))
    png = tmp_path / event["file"]
    data = bytearray(png.read_bytes())
    data[-20] ^= 0xFF
    png.write_bytes(bytes(data))
    assert "does not match its checksum" in frame_problem(tmp_path, event)
    with pytest.raises(InputError, match="retake it"):
        load_frame(tmp_path, event)
    (tmp_path / event["sidecar"]).unlink()
    png.unlink()
    assert frame_problem(tmp_path, event) == "frames/a.png is missing"


def test_a_torn_last_line_is_cut_and_appends_continue(tmp_path):
    path = tmp_path / "journal.jsonl"
    with Journal(path) as journal:
        journal.append({"event": "start"})
        journal.append({"event": "pose", "n": 1})
    with path.open("ab") as f:
        f.write(b'{"event": "pose", "n"')  # the power went out here
    assert read_journal(path) == [{"event": "start"}, {"event": "pose", "n": 1}]
    with Journal(path) as journal:
        assert len(journal.events) == 2
        assert not journal.damaged  # a torn tail is a crash, not damage
        journal.append({"event": "pose", "n": 2})
    assert [e.get("n") for e in read_journal(path)] == [None, 1, 2]
    assert not (tmp_path / DAMAGED).exists()


def test_damaged_lines_are_reported_and_set_aside_by_a_writer(tmp_path):
    """Reading reports a damaged line (number, problem) and leaves it out; opening to write keeps it in
    journal.damaged and rewrites the journal without it, byte for byte otherwise."""
    path = tmp_path / "journal.jsonl"
    good = '{"event": "start"}\n{"event": "end"}\n'
    path.write_text('{"event": "start"}\n{"event": "fr\n{"event": "end"}\n[1, 2]\n')
    contents = load_journal(path)
    assert [e["event"] for e in contents.events] == ["start", "end"]
    assert [(d.line, d.problem[:8]) for d in contents.damaged] == [(2, "not JSON"), (4, "not an e")]
    with Journal(path) as journal:
        assert [d.line for d in journal.damaged] == [2, 4]
        journal.append({"event": "more"})
    assert path.read_text() == good + '{"event": "more"}\n'
    aside = [json.loads(line) for line in (tmp_path / DAMAGED).read_text().splitlines()]
    assert [(a["line"], a["text"]) for a in aside] == [(2, '{"event": "fr'), (4, "[1, 2]")]


CHILD = textwrap.dedent(
    """
    import sys
    from pathlib import Path
    import numpy as np
    from hlr_lab.session.frames import store_frame
    from hlr_lab.session.journal import Journal

    session = Path(sys.argv[1])
    rng = np.random.default_rng(1)
    with Journal(session / "journal.jsonl") as journal:
        print("ready", flush=True)
        for i in range(100000):
            pixels = rng.integers(0, 4096, size=(120, 160, 3)).astype(np.uint16)
            fields = {"pose": f"f{i:05d}", "exposure_index": 0, "dark": False, "exposure_s": 0.01}
            stored = store_frame(session, f"f{i:05d}", pixels, fields)
            journal.append({"event": "frame", "i": i, **fields, "adaptive": False, "clipped_pixels": 0,
                            **stored.files()})
    """
)


def test_a_killed_acquisition_loses_no_journaled_frame(tmp_path):
    """SIGKILL (no cleanup at all) at an arbitrary moment: every frame the journal holds is intact."""
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    assert child.stdout.readline().strip() == "ready"
    time.sleep(1.0)
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    child.stdout.close()
    with Journal(tmp_path / "journal.jsonl") as journal:  # opening repairs a torn last line
        events = journal.events
    assert len(events) > 5
    assert [e["i"] for e in events] == list(range(len(events)))
    assert all(frame_problem(tmp_path, e) is None for e in events)
    # what was cut off is at most the one frame in flight, never referenced by the journal
    journaled = {e["file"] for e in events} | {e["sidecar"] for e in events}
    leftovers = {f"frames/{p.name}" for p in (tmp_path / "frames").iterdir()} - journaled
    assert len(leftovers) <= 3  # image, sidecar and one temporary of the interrupted frame


def test_a_damaged_session_record_is_named(tmp_path, rig, plan_file):
    plan = tmp_path / "plan.json"
    plan.write_bytes(plan_file[0].read_bytes())
    assert start_or_resume(tmp_path, plan, "a" * 64, rig, force=False) is False
    assert start_or_resume(tmp_path, plan, "a" * 64, rig, force=False) is True
    with pytest.raises(InputError, match="started with another plan"):
        start_or_resume(tmp_path, plan, "b" * 64, rig, force=False)
    (tmp_path / SESSION).write_text('{"format": "hlr-lab.session", "version": 1, "plan": {}}')
    with pytest.raises(InputError, match="session record is damaged") as err:
        start_or_resume(tmp_path, plan, "a" * 64, rig, force=False)
    assert str(tmp_path / SESSION) in str(err.value)


def test_the_frame_writer_stores_every_queued_frame_and_journals_it(tmp_path):
    frames = {f"f{i}": np.full((4, 5), i, np.uint16) for i in range(5)}
    with Journal(tmp_path / "journal.jsonl") as journal, FrameWriter(tmp_path, journal, depth=1) as writer:
        for name, pixels in frames.items():
            fields = frame_fields(pose=name)
            writer.submit(name, pixels, fields, {**fields, "adaptive": False, "clipped_pixels": 0})
    events = read_journal(tmp_path / "journal.jsonl")
    assert [e["pose"] for e in events] == list(frames)
    assert writer.stored == len(frames)
    for e in events:
        assert np.array_equal(load_frame(tmp_path, e), frames[e["pose"]])


def test_a_storing_failure_stops_the_run_and_later_frames_are_not_stored(tmp_path):
    """A frame that cannot be stored (here: its name is taken, as a full disk would fail a write) is
    raised in the acquiring thread at its next submit or at close; nothing after it is stored."""
    store_frame(tmp_path, "taken", np.zeros((2, 2), np.uint16), {})
    with Journal(tmp_path / "journal.jsonl") as journal:
        writer = FrameWriter(tmp_path, journal)
        with pytest.raises(FileExistsError):
            _submit_then_close(writer, ["taken", "after"])
    assert read_journal(tmp_path / "journal.jsonl") == []
    assert not (tmp_path / "frames" / "after.png").exists()


def _submit_then_close(writer, names):
    """The failure surfaces at the second submit or at close (a race between the threads): both right."""
    try:
        for name in names:
            fields = frame_fields(pose=name)
            writer.submit(
                name, np.ones((2, 2), np.uint16), fields, {**fields, "adaptive": False, "clipped_pixels": 0}
            )
    finally:
        writer.close()


def test_stored_files_get_the_mode_open_would_give(tmp_path):
    """Not mkstemp's private 0600: a lab's colleagues (and its backup) can read a session."""
    stored = store_frame(tmp_path, "f", np.zeros((2, 2), np.uint16), {})
    for name in (stored.file, stored.sidecar):
        assert (tmp_path / name).stat().st_mode & 0o777 == FILE_MODE


def test_a_session_keeps_its_plan_and_the_objects_files_so_it_can_move(plan_file, rig, tmp_path, caplog):
    """start_or_resume copies the plan, a textured OBJ, its material library and the image that names
    into session/object; the session moved elsewhere, with the originals gone, loads the same mesh
    (sha256 and texture) from its copies. A file the OBJ names outside its folder is not followed, and
    said so."""
    import cv2

    from hlr_lab.formats.plan import read_plan, write_plan
    from hlr_lab.formats.planned_object import load_planned_mesh
    from hlr_lab.formats.regions import RegionEntry
    from hlr_lab.object.mesh import file_sha256
    from hlr_lab.session.metadata import read_record, session_plan

    meshes = tmp_path / "work" / "meshes"
    (meshes / "maps").mkdir(parents=True)
    cv2.imwrite(str(meshes / "maps" / "paint.png"), np.full((8, 8, 3), (40, 90, 200), np.uint8))
    (meshes / "quad.mtl").write_text("newmtl paint\nKd 1 1 1\nmap_Kd maps/paint.png\nbump ../elsewhere.png\n")
    (meshes / "quad.obj").write_text(
        "mtllib quad.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "usemtl paint\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
    )
    plan = read_plan(plan_file[0])
    ref = {"mesh": "meshes/quad.obj", "sha256": file_sha256(meshes / "quad.obj"),
           "regions": [RegionEntry(id=0, color=[40, 90, 200], vertices=4, faces=2)]}  # fmt: skip
    plan_path = tmp_path / "work" / "plan.json"
    write_plan(plan_path, plan.model_copy(update={"object": plan.object.model_copy(update=ref)}))
    before = load_planned_mesh(read_plan(plan_path), plan_path)
    assert before.texture is not None

    session = tmp_path / "session"
    session.mkdir()
    start_or_resume(session, plan_path, file_sha256(plan_path), rig, force=False)
    assert "elsewhere.png" in caplog.text
    assert sorted(p.relative_to(session).as_posix() for p in (session / "object").rglob("*") if p.is_file()) == [
        "object/maps/paint.png", "object/plan.json", "object/quad.mtl", "object/quad.obj"
    ]  # fmt: skip
    moved = tmp_path / "archive" / "renamed"
    moved.parent.mkdir()
    session.rename(moved)
    (tmp_path / "work").rename(tmp_path / "gone")
    kept, kept_path = session_plan(moved, read_record(moved))
    after = load_planned_mesh(kept, kept_path)
    assert after.sha256 == before.sha256
    np.testing.assert_array_equal(after.texture, before.texture)
    assert kept.poses == plan.poses
