"""``hlr-lab calibrate``'s refusals on the simulated rig (what the procedures measure — ``bench
calibration``'s ``calibrate all``, its camera and gantry photographs solved again with --from — is in
test_calibrate_bench.py)."""

from __future__ import annotations

import io
import re
import shutil
from pathlib import Path

import pytest

from calibration.procedures import default_folder
from hlr_lab.cli.main import main

pytestmark = pytest.mark.renderer  # the simulated rig renders its frames

SIM_RIG = Path(__file__).resolve().parents[1] / "hlr_lab" / "data" / "sim-rig.toml"


def test_a_rig_file_without_a_lamp_is_refused_before_anything_moves(tmp_path, capsys):
    """Every procedure lights its target with the lamp: without a [lamp] relay, one line naming the rig
    file's section, and no photographs' folder. (The relay's stand-in refuses the same way for a library
    caller who skipped the check: hlr_lab.instrument.control.)"""
    text = SIM_RIG.read_text()
    bare = tmp_path / "rig.toml"
    bare.write_text(re.sub(r"(?ms)^\[lamp\].*?(?=^\[)", "", text))
    for procedure in ("camera", "radiometric", "all"):
        out = tmp_path / procedure
        command = [
            "calibrate",
            procedure,
            "--rig",
            str(bare),
            "--sim",
            "--out",
            str(out),
            "-o",
            str(tmp_path / "c.toml"),
        ]
        assert main(command) == 1
        assert re.search(
            r"rig\.toml: lamp: calibration switches the lamp: add a \[lamp\]", capsys.readouterr().err
        )
        assert not out.exists()


def test_a_rig_file_without_a_board_or_a_used_folder_is_refused(tmp_path, capsys):
    text = SIM_RIG.read_text()
    bare = tmp_path / "rig.toml"
    bare.write_text(text[: text.index("[calibration.board]")])
    assert main(["calibrate", "camera", "--rig", str(bare), "--sim", "-o", str(tmp_path / "c.toml")]) == 1
    assert re.search(
        r"calibration\.board: no \[calibration\.board\]: describe the ChArUco board", capsys.readouterr().err
    )
    used = tmp_path / "used"
    used.mkdir()
    (used / "x").write_text("")
    assert main(["calibrate", "camera", "--sim", "--out", str(used), "-o", str(tmp_path / "c.toml")]) == 1
    assert "the folder is not empty" in capsys.readouterr().err
    assert not (tmp_path / "c.toml").exists()
    shutil.rmtree(used)


def test_photographs_go_to_the_current_folder_and_a_failed_run_leaves_no_folder(
    tmp_path, monkeypatch, capsys
):
    """Without --out the photographs' folder is calibration/DATE-PROCEDURE in the current folder (never
    beside the rig file, which may be the installed package's); a run that fails before its first
    photograph (here: no device answers on the example rig file's links) leaves no folder behind."""
    rig = tmp_path / "rig.toml"
    example = Path(__file__).resolve().parents[1] / "docs" / "rig.example.toml"
    port = "/dev/serial/by-id/usb-FTDI_USB__-__Serial_Converter_FT4TFSV1-if00-port0"
    rig.write_text(example.read_text().replace(port, str(tmp_path / "no-such-port")))
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    for procedure in ("camera", "all"):
        monkeypatch.setattr("sys.stdin", io.StringIO("y\n" * 4))  # the operator says the target is in place
        assert main(["calibrate", procedure, "--rig", str(rig), "-o", str(tmp_path / "c.toml")]) == 1
        assert "no-such-port" in capsys.readouterr().err
        assert list(work.iterdir()) == [], f"calibrate {procedure} left {list(work.rglob('*'))}"
        assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.toml", "work"]
    assert default_folder("camera", "2026-12-01-093000") == Path("calibration/2026-12-01-093000-camera")


def test_a_calibrated_file_over_its_rig_file_a_session_or_a_photograph_is_refused_before_anything_moves(
    tmp_path, capsys
):
    """``-o`` is checked as every command's output is (docs/sessions.md, "Outputs never destroy inputs"),
    before the first photograph: not over the rig file it calibrates, not over a session's journal (the
    file that once took a night's measurement), not over a photograph solved again with --from, not
    through a link; ``calibrate all`` not over its own intermediate file. Nothing is written."""
    rig = tmp_path / "rig.toml"
    rig.write_text(SIM_RIG.read_text())
    session = tmp_path / "session"
    session.mkdir()
    (session / "session.json").write_text("{}")
    journal = session / "journal.jsonl"
    journal.write_text("a night\n")
    photographs = tmp_path / "photographs"
    (photographs / "frames").mkdir(parents=True)
    (photographs / "frames" / "v00.png").write_bytes(b"a photograph")
    (tmp_path / "link.toml").symlink_to(tmp_path / "elsewhere.toml")
    out = tmp_path / "out"
    refusals = [
        (["camera", "--rig", str(rig), "--sim", "--out", str(out), "-o", str(rig)], "is also this command's input"),
        (["all", "--rig", str(rig), "--sim", "--out", str(out), "-o", str(rig)], "is also this command's input"),
        (["gantry", "--sim", "--out", str(out), "-o", str(journal)], "is one of the session"),
        (["all", "--sim", "--out", str(out), "-o", str(journal)], "is one of the session"),
        (["camera", "--sim", "--from", str(photographs), "-o", str(photographs / "frames" / "v00.png")],
         "is also this command's input"),
        (["all", "--sim", "--out", str(out), "-o", str(out / "rig-camera.toml")], "is written twice"),
        (["radiometric", "--sim", "--out", str(out), "-o", str(tmp_path / "link.toml")], "symbolic link"),
    ]  # fmt: skip
    for command, said in refusals:
        assert main(["calibrate", *command]) == 1, command
        err = " ".join(capsys.readouterr().err.split())
        assert said in err, (command, err)
        assert "--output" in err, (command, err)
        assert not out.exists(), command
    assert rig.read_text() == SIM_RIG.read_text()
    assert journal.read_text() == "a night\n"
    assert (photographs / "frames" / "v00.png").read_bytes() == b"a photograph"
    assert not (tmp_path / "elsewhere.toml").exists()
