"""A journal that cannot be fooled: a finished session, damaged one way at a time, then ``fit`` and
``acquire`` (resume). Each damage is found and named; ``fit`` never fits on less than the plan asks for
without saying so; a resumed run sets damaged lines aside, retakes what they described, and the session
fits again."""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from hlr_lab.cli.main import main
from hlr_lab.formats.plan import read_plan
from hlr_lab.session.journal import DAMAGED, JOURNAL, read_journal
from tests.films import resume_command

pytestmark = pytest.mark.renderer  # the simulated rig renders its frames


@pytest.fixture
def finished(finished_session) -> Path:
    return finished_session


def _lines(session: Path) -> list[str]:
    return (session / JOURNAL).read_text().splitlines(keepends=True)


def _frame_line(session: Path, which: int = -1) -> int:
    """Index (from 0) of a frame line of the journal: the last one by default."""
    frames = [i for i, line in enumerate(_lines(session)) if '"event": "frame"' in line]
    return frames[which]


def _edit_frame(key: str, value) -> Callable[[Path], None]:
    def damage(session: Path) -> None:
        lines = _lines(session)
        i = _frame_line(session, 1)
        event = json.loads(lines[i])
        event[key] = value
        lines[i] = json.dumps(event, sort_keys=True) + "\n"
        (session / JOURNAL).write_text("".join(lines))

    return damage


def _cut_last_frame_line(session: Path) -> None:
    """A crash while the last frame line was written: the journal ends in half of it."""
    lines = _lines(session)
    i = _frame_line(session)
    (session / JOURNAL).write_text("".join(lines[:i]) + lines[i][: len(lines[i]) // 2])


def _flip_sidecar_byte(session: Path) -> None:
    sidecar = session / json.loads(_lines(session)[_frame_line(session, 0)])["sidecar"]
    data = bytearray(sidecar.read_bytes())
    data[len(data) // 2] ^= 0x80
    sidecar.write_bytes(bytes(data))


def _rename_key(session: Path) -> None:
    lines = _lines(session)
    i = _frame_line(session, 2)
    lines[i] = lines[i].replace('"sha256"', '"sha25X"')
    (session / JOURNAL).write_text("".join(lines))


def _garbage_line(session: Path) -> None:
    lines = _lines(session)
    lines.insert(3, "}}not json at all\n")
    (session / JOURNAL).write_text("".join(lines))


DAMAGES = {  # damage → (what fit says, the number of frames a resumed run takes)
    "last frame line cut off": (_cut_last_frame_line, r"1 planned frame\(s\) are not in the session", 1),
    "exposure_index edited": (_edit_frame("exposure_index", 7), r"disagree on exposure_index", 1),
    "pose edited": (_edit_frame("pose", "p999"), r"disagree on pose", 1),
    "sidecar byte flipped": (_flip_sidecar_byte, r"does not match its checksum", 1),
    "key of a frame line damaged": (_rename_key, r"journal.jsonl line \d+: frame line without 'sha256'", 1),
    "a line that is not JSON": (_garbage_line, None, 0),
}


@pytest.mark.slow
@pytest.mark.parametrize("damage", DAMAGES)
def test_each_damage_is_named_and_a_resume_mends_it(
    damage, finished, builtin_plan, quarter_rig, tmp_path, capsys
):
    make, said, retaken = DAMAGES[damage]
    session = tmp_path / "session"
    shutil.copytree(finished, session)
    make(session)
    fit = ["fit", str(session), "-o", str(tmp_path / "m.json")]
    if said is None:  # nothing the plan needs is lost: fit goes on, naming the line it did not use
        assert main(fit) == 0
        assert re.search(r"not used: journal.jsonl line 4: not JSON", capsys.readouterr().err)
    else:
        assert main(fit) == 1
        err = capsys.readouterr().err
        assert re.search(said, err), err
        assert "--allow-incomplete" in err
        assert "internal error" not in err
        assert not (tmp_path / "m.json").exists()

    resume = resume_command(builtin_plan, quarter_rig, session)
    assert main(resume) == 0
    assert re.search(rf"frames taken\s+│\s+{retaken} ", capsys.readouterr().err)
    events = read_journal(session / JOURNAL)
    frames = [e for e in events if e["event"] == "frame"]
    plan = read_plan(builtin_plan)
    wanted = {(p.id, k) for p in plan.poses for k in range(len(p.exposures_s))}
    assert wanted <= {(e["pose"], e["exposure_index"]) for e in frames}
    if damage in ("key of a frame line damaged", "a line that is not JSON"):
        aside = (session / DAMAGED).read_text().splitlines()
        assert len(aside) == 1  # the line is kept, out of the journal
    assert main(fit) == 0
    capsys.readouterr()


@pytest.mark.slow
def test_a_stopped_session_is_refused_with_what_is_missing_and_fits_with_allow_incomplete(
    finished, tmp_path, capsys
):
    """A run stopped after its first pose (as when it was stopped by a fault): fit lists the missing frames;
    --allow-incomplete fits and materials.json records what was missing."""
    session = tmp_path / "session"
    shutil.copytree(finished, session)
    lines = _lines(session)
    first_pose = json.loads(lines[_frame_line(session, 0)])["pose"]
    kept = [line for line in lines if '"event": "frame"' not in line or f'"pose": "{first_pose}"' in line]
    (session / JOURNAL).write_text("".join(kept))
    assert main(["fit", str(session)]) == 1
    err = capsys.readouterr().err
    assert re.search(r"3 planned frame\(s\) are not in the session \(\w+ exposure 0, ", err), err
    assert main(["fit", str(session), "--allow-incomplete"]) == 0
    assert "3 planned frame(s) missing" in capsys.readouterr().err
    materials = json.loads((session / "materials.json").read_text())
    assert len(materials["incomplete"]["missing_frames"]) == 3


def test_a_frame_that_is_not_what_the_rig_took_is_refused_although_its_checksums_agree(
    finished_session, tmp_path, capsys
):
    """An 8-bit PNG in place of a 16-bit frame, every checksum updated to match (a careful hand): it
    once gave Rd 0.0144 for a true 0.0254 with exit status 0; now fit refuses naming the frame. So does
    a frame of another size."""
    import hashlib

    import cv2
    import numpy as np

    for what, forge in (
        ("8-bit", lambda px: (px >> 8).astype(np.uint8)),
        ("another size", lambda px: np.ascontiguousarray(px[:-2, :-2])),
    ):
        session = tmp_path / what.replace(" ", "-")
        shutil.copytree(finished_session, session)
        lines = _lines(session)
        i = _frame_line(session, 0)
        event = json.loads(lines[i])
        png = session / event["file"]
        pixels = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        ok, data = cv2.imencode(".png", forge(pixels))
        assert ok
        png.write_bytes(data.tobytes())
        sidecar_path = session / event["sidecar"]
        sidecar = json.loads(sidecar_path.read_text())
        sidecar["image_sha256"] = hashlib.sha256(data.tobytes()).hexdigest()
        sidecar_path.write_text(json.dumps(sidecar))
        event["sha256"] = sidecar["image_sha256"]
        event["sidecar_sha256"] = hashlib.sha256(sidecar_path.read_bytes()).hexdigest()
        lines[i] = json.dumps(event, sort_keys=True) + "\n"
        (session / JOURNAL).write_text("".join(lines))
        assert main(["fit", str(session)]) == 1
        err = capsys.readouterr().err
        assert event["file"] in err
        assert ("8-bit image" if what == "8-bit" else "pixels, the rig's camera") in err
