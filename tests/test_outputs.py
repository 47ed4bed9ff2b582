"""An output never destroys an input (issue 20, §2): a command refuses, before it does its work, to write
over one of its own inputs (by any name), over a session's own files, twice under one name, into a
folder, under an empty name or one its format cannot carry, and over a companion (.mtl, scene.xml) that
is not hlr-lab's. Each refused case leaves every file as it was."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from hlr_lab.cli.main import main
from hlr_lab.errors import InputError
from hlr_lab.formats.materials import PixelCounts, materials_file, unmeasured_entry, write_materials
from hlr_lab.formats.regions import RegionEntry
from hlr_lab.object.mesh import load_mesh
from hlr_lab.object.segment import segment
from hlr_lab.session.outputs import check_outputs, declared_format


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {
        p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def _refused(capsys, command: list[str], *words: str) -> str:
    assert main(command) in (1, 2)  # 1: a refused input; 2: an option click refuses
    err = " ".join(capsys.readouterr().err.split())
    assert "internal error" not in err
    for word in words:
        assert word in err, err
    return err


@pytest.fixture
def painted_ply(tmp_path) -> Path:
    """A small mesh with two vertex colours: a PLY that segment and plan read."""
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.03)
    colours = np.where(sphere.vertices[:, 2:3] > 0, [200, 40, 40, 255], [40, 40, 200, 255]).astype(np.uint8)
    sphere.visual.vertex_colors = colours
    path = tmp_path / "m.ply"
    sphere.export(path)
    return path


@pytest.fixture
def textured_obj(tmp_path) -> tuple[Path, Path]:
    """A textured OBJ (quad.obj, quad.mtl, maps/paint.png) and a materials.json for it."""
    meshes = tmp_path / "meshes"
    (meshes / "maps").mkdir(parents=True)
    cv2.imwrite(str(meshes / "maps" / "paint.png"), np.full((8, 8, 3), (40, 90, 200), np.uint8))
    (meshes / "quad.mtl").write_text("newmtl paint\nKd 1 1 1\nmap_Kd maps/paint.png\n")
    obj = meshes / "quad.obj"
    obj.write_text(
        "mtllib quad.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "usemtl paint\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
    )
    seg = segment(load_mesh(obj, need_colour=True))
    entries = [
        unmeasured_entry(RegionEntry.of(r), [0.2, 0.3, 0.5], [0.001] * 3, reason="a test", theta_c_deg=10.0,
                         pixels=PixelCounts(diffuse=900, highlight=0), residual_rms=0.0, estimator="robust")
        for r in seg.regions
    ]  # fmt: skip
    materials = tmp_path / "materials.json"
    write_materials(materials, materials_file(entries, mesh=str(obj), sha256=""))
    return obj, materials


# -- the rule itself ---------------------------------------------------------------------------------------


def test_an_output_that_is_an_input_by_any_name_is_refused(tmp_path):
    source = tmp_path / "mesh.ply"
    source.write_bytes(b"ply\n")
    (tmp_path / "sub").mkdir()
    hard = tmp_path / "hard.ply"
    os.link(source, hard)
    for output in (source, tmp_path / "sub" / ".." / "mesh.ply", hard):
        with pytest.raises(InputError, match="is also this command's input"):
            check_outputs([output], [source])
    alias = tmp_path / "alias.ply"
    alias.symlink_to(source)
    with pytest.raises(InputError, match="is a symbolic link"):
        check_outputs([alias], [source])
    check_outputs([tmp_path / "regions.json"], [source, None, "builtin:pebble"])  # another name: fine


def test_a_sessions_own_files_are_never_an_output_but_its_products_are(tmp_path):
    session = tmp_path / "s"
    (session / "frames").mkdir(parents=True)
    (session / "session.json").write_text("{}")
    for name in ("journal.jsonl", "session.json", "journal.reserve", "acquire.lock", "acquire.log",
                 "frames/p000_e0.png", "object/plan.json", "object/maps/paint.png"):  # fmt: skip
        with pytest.raises(InputError, match="own files"):
            check_outputs([session / name])
    check_outputs([session / "materials.json", session / "fit-diagnostics.json", session / "report.html"])
    check_outputs([session / "materials-paper.json"])


def test_two_outputs_under_one_name_a_folder_and_a_control_character_are_refused(tmp_path):
    with pytest.raises(InputError, match="written twice"):
        check_outputs([tmp_path / "fit-diagnostics.json", tmp_path / "fit-diagnostics.json"])
    (tmp_path / "folder").mkdir()
    with pytest.raises(InputError, match="is a folder"):
        check_outputs([tmp_path / "folder"])
    with pytest.raises(InputError, match="control character"):
        check_outputs([tmp_path / "a\nb.obj"])


# -- the commands --------------------------------------------------------------------------------------------


def test_segment_and_plan_refuse_to_write_over_their_inputs(painted_ply, tmp_path, capsys):
    regions = tmp_path / "r.json"
    assert main(["segment", "--mesh", str(painted_ply), "-o", str(regions)]) == 0
    before = _snapshot(tmp_path)
    _refused(capsys, ["segment", "--mesh", str(painted_ply), "-o", str(painted_ply)], "m.ply", "input")
    _refused(capsys, ["plan", "--mesh", str(painted_ply), "--sim", "-o", str(painted_ply)], "m.ply", "input")
    _refused(capsys, ["plan", "--mesh", str(painted_ply), "--regions", str(regions), "--sim", "-o", str(regions)],
             "r.json", "input")  # fmt: skip
    assert _snapshot(tmp_path) == before


def test_paint_refuses_to_write_over_the_mesh_it_paints_or_into_a_session(painted_ply, tmp_path, capsys):
    session = tmp_path / "session"
    (session / "object").mkdir(parents=True)
    (session / "session.json").write_text("{}")
    before = _snapshot(tmp_path)
    _refused(
        capsys,
        ["paint", "--mesh", str(painted_ply), "--regions", "2", "-o", str(painted_ply)],
        "m.ply",
        "input",
    )
    _refused(capsys, ["paint", "--mesh", str(painted_ply), "--regions", "2", "-o", str(session / "object" / "p.ply")],
             "session")  # fmt: skip
    assert _snapshot(tmp_path) == before


def test_an_hlr_lab_file_of_another_kind_is_not_written_over_but_one_of_the_same_kind_is(
    painted_ply, builtin_plan, finished_session, tmp_path, capsys
):
    """A mistyped ``-o`` that names an existing hlr-lab file of another kind (its declared ``format``) is
    refused: regions over a plan, a plan over regions, a report over the plan a resumed run needs, regions
    over a rig file (its format line after its comments), a calibrated rig file over a plan, before any
    photograph. The same kind is written again."""
    plan = tmp_path / "plan.json"
    plan.write_bytes(builtin_plan.read_bytes())
    regions = tmp_path / "regions.json"
    assert main(["segment", "--mesh", str(painted_ply), "-o", str(regions)]) == 0
    rig = tmp_path / "rig.toml"
    rig.write_text('# a rig file\n# with comments first\n[rig]\nformat = "hlr-lab.rig"\nversion = 1\n')
    before = _snapshot(tmp_path)
    _refused(
        capsys,
        ["segment", "--mesh", str(painted_ply), "-o", str(plan)],
        "plan.json: --output: is an hlr-lab.plan file, and this command would write an hlr-lab.regions file",
    )
    _refused(
        capsys,
        ["plan", "--mesh", str(painted_ply), "--sim", "-o", str(regions)],
        "is an hlr-lab.regions file",
    )
    _refused(
        capsys,
        ["report", str(finished_session), "-o", str(plan)],
        "is an hlr-lab.plan file, and this command would write a file of another kind",
    )
    _refused(capsys, ["segment", "--mesh", str(painted_ply), "-o", str(rig)], "is an hlr-lab.rig file")
    _refused(
        capsys,
        ["calibrate", "camera", "--sim", "-o", str(plan)],
        "is an hlr-lab.plan file, and this command would write an hlr-lab.rig file",
    )
    assert _snapshot(tmp_path) == before
    assert main(["segment", "--mesh", str(painted_ply), "--delta-e", "9", "-o", str(regions)]) == 0
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)  # not read to learn its kind (a read would block): written over as any file would be
    assert declared_format(fifo) is None


def test_export_refuses_the_input_mesh_its_library_and_a_library_it_did_not_write(
    textured_obj, tmp_path, capsys
):
    obj, materials = textured_obj
    export = ["export", str(materials), "--mesh", str(obj), "--format", "obj", "-o"]
    before = _snapshot(tmp_path)
    _refused(capsys, [*export, str(obj)], "quad")  # the mesh, and its quad.mtl beside it
    _refused(capsys, [*export, str(obj.with_name("quad.OBJ"))], "quad.mtl")  # another OBJ, the same library
    notes = tmp_path / "notes.mtl"
    notes.write_text("my own notes\n")
    _refused(capsys, [*export, str(tmp_path / "notes.obj")], "notes.mtl", "did not write")
    assert notes.read_text() == "my own notes\n"
    _refused(capsys, [*export, str(tmp_path / "a b.obj")], "spaces")
    _refused(capsys, [*export, str(tmp_path / "a\nb.obj")], "control character")
    assert _snapshot(tmp_path) == {**before, "notes.mtl": b"my own notes\n"}
    out = tmp_path / "out" / "quad.obj"
    for _ in range(2):  # the second time over its own .mtl: hlr-lab wrote it
        assert main([*export, str(out)]) == 0
    assert (out.with_suffix(".mtl")).read_text().startswith("# hlr-lab materials")


def test_an_empty_output_is_refused_by_every_command_that_writes(builtin_plan, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _refused(capsys, ["acquire", "--plan", str(builtin_plan), "--sim", "--out", ""], "empty path")
    _refused(capsys, ["segment", "--mesh", "builtin:pebble", "-o", ""], "empty path")
    assert list(tmp_path.iterdir()) == []


def test_a_long_legal_output_name_is_written(tmp_path):
    """A name of 250 bytes is legal (NAME_MAX 255); the temporary beside it must not be longer."""
    output = tmp_path / ("r" * 245 + ".json")
    assert main(["segment", "--mesh", "builtin:pebble", "-o", str(output)]) == 0
    assert output.is_file()
    assert [p.name for p in tmp_path.iterdir()] == [output.name]  # no temporary left


@pytest.mark.filterwarnings("always::PIL.Image.DecompressionBombWarning")  # as outside the tests
def test_a_librarys_warning_is_one_line(textured_obj, tmp_path, capsys, monkeypatch):
    """PIL's DecompressionBombWarning (here for a 40 × 40 texture under a lowered limit) is one console
    line, not Python's file:line and source dump."""
    from PIL import Image

    texture = tmp_path / "big.png"
    cv2.imwrite(str(texture), np.full((40, 40, 3), 128, np.uint8))
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)  # 1600 pixels: above it, below twice it (an error)
    obj, _ = textured_obj
    assert (
        main(["segment", "--mesh", str(obj), "--texture", str(texture), "-o", str(tmp_path / "r.json")]) == 0
    )
    err = capsys.readouterr().err
    said = [line for line in err.splitlines() if "exceeds limit" in line]
    assert said, err
    assert all(line.startswith("warning: Image size (1600 pixels) exceeds limit") for line in said), err
    assert "warnings.warn" not in err
    assert ".py:" not in err
