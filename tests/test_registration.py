"""``hlr-lab register`` on the simulated rig (issue 22): the object moved where the plan does not expect
it, photographed through the real drivers (the registration plan run by acquisition), its placement
measured, the plan made again for it; solved again from the kept photographs; photographs that are not
this plan's refused; the summary page."""

from __future__ import annotations

import json
import re
import shutil
from importlib import resources

import numpy as np
import pytest
import trimesh

from hlr_lab.cli.main import main
from hlr_lab.formats.plan import read_plan
from hlr_lab.formats.planned_object import (
    load_planned_mesh,
    mesh_to_turntable,
    placement_line,
    planned_segmentation,
)
from hlr_lab.instrument.motion import motion_targets
from hlr_lab.placement.pose import rotation_error_deg, vertex_errors_mm
from hlr_lab.rig.file import sim_rig
from tests.renderer_guard import require_renderer

OFFSET = (12.0, -8.0, 200.0)  # mm, mm, degrees: well off the axis, turned more than half a turn


@pytest.fixture(scope="module")
def registered(builtin_plan, tmp_path_factory):
    """The pebble 12, −8 mm off and turned 200°, acquired with ``--register``: registered where it lies,
    the placed plan run: (plan, placed plan, photographs, session)."""
    require_renderer()
    folder = tmp_path_factory.mktemp("register")
    session = folder / "s"
    offset = ",".join(f"{v:g}" for v in OFFSET)
    command = ["acquire", "--plan", str(builtin_plan), "--sim", "--object-offset", offset, "--register", "--out",
               str(session), "--speed-factor", "50"]  # fmt: skip
    assert main(command) == 0
    return builtin_plan, folder / "s-placed.json", folder / "s-registration", session


def _truth(plan_path):
    from worlds.plan_world import ObjectOffset

    dx, dy, yaw = OFFSET
    return ObjectOffset(dx / 1000, dy / 1000, yaw).moved(mesh_to_turntable(read_plan(plan_path)))


def test_register_measures_where_the_object_lies_and_plans_again_for_it(registered):
    """Every vertex within 0.3 mm RMS and 0.6 mm worst of where it really lies, the rotation within 0.4°
    (the pebble is nearly round about its axis: its turn is its least certain number; bench register's
    figures for the bunny and Spot hold the 0.15° target), the record saying so within its errors, and a
    plan made for the measured placement that the rig can run."""
    plan_path, placed_path, photos, _ = registered
    placed = read_plan(placed_path)
    truth = _truth(plan_path)
    found = mesh_to_turntable(placed)
    vertices = load_planned_mesh(placed, placed_path).vertices
    errors = vertex_errors_mm(vertices, found, truth)
    assert np.sqrt(np.mean(errors**2)) <= 0.3
    assert errors.max() <= 0.6
    assert rotation_error_deg(found, truth) <= 0.4
    record = placed.object.placement
    assert record is not None
    assert (record.status, record.method) == ("measured", "outlines")
    assert record.photographs == str(photos.resolve())
    assert record.nominal_mesh_to_turntable == read_plan(plan_path).object.mesh_to_turntable
    assert record.offset_shift_mm is not None
    assert np.allclose(record.offset_shift_mm[:2], OFFSET[:2], atol=0.3)
    assert abs((record.offset_turn_deg or 0) - (OFFSET[2] - 360)) <= 0.4
    assert (record.residual_px or 1.0) < 0.6
    # planned again: the lights' places on the object moved with it, the regions are the plan's own
    plan = read_plan(plan_path)
    assert placed.object.regions == plan.object.regions
    assert placed.object.sha256 == plan.object.sha256
    before = {p.id: p.light.position_mesh_m for p in plan.poses}
    assert any(before.get(p.id) != p.light.position_mesh_m for p in placed.poses)
    assert motion_targets(placed, sim_rig(), placed_path)
    assert all(c.satisfied for c in placed.coverage.values())


def test_the_summary_page_shows_every_view_with_the_registered_outline(registered):
    _, _, photos, _ = registered
    page = (photos / "summary.html").read_text()
    assert page.count("<figure>") == 6
    assert len(re.findall(r"<figcaption>turntable -?\d+°: outline \d+\.\d\d px RMS", page)) == 6
    assert "where the object lies" in page.lower()


def test_register_solves_again_from_its_photographs_without_the_rig(registered, tmp_path):
    """--from: the same placement from the kept photographs alone (no simulated world started)."""
    plan_path, placed_path, photos, _ = registered
    again = tmp_path / "again.json"
    assert main(["register", "--plan", str(plan_path), "--sim", "--from", str(photos), "-o", str(again)]) == 0
    assert np.allclose(
        mesh_to_turntable(read_plan(again)), mesh_to_turntable(read_plan(placed_path)), atol=1e-9
    )


def test_photographs_of_another_object_or_plan_are_refused(registered, tmp_path, capsys):
    """Photographs of another object (--from), and a folder of another registration (--out), are refused
    naming the folder, and no placed plan is written."""
    _, _, photos, _ = registered
    box = trimesh.creation.box((0.05, 0.04, 0.03))
    colours = np.tile([200, 60, 40, 255], (len(box.vertices), 1)).astype(np.uint8)
    mesh_path = tmp_path / "box.ply"
    trimesh.Trimesh(box.vertices, box.faces, vertex_colors=colours, process=False).export(mesh_path)
    other = tmp_path / "box-plan.json"
    assert main(["plan", "--mesh", str(mesh_path), "--sim", "-o", str(other)]) == 0
    placed = tmp_path / "placed.json"
    assert main(["register", "--plan", str(other), "--sim", "--from", str(photos), "-o", str(placed)]) == 1
    assert "holds the photographs of another object" in capsys.readouterr().err
    assert not placed.exists()
    copy = tmp_path / "photos"
    shutil.copytree(photos, copy)
    assert main(["register", "--plan", str(other), "--sim", "--out", str(copy), "-o", str(placed)]) == 1
    assert "holds the photographs of another plan or rig" in capsys.readouterr().err
    assert not placed.exists()


def test_a_plans_regions_become_the_planners_segmentation(builtin_plan):
    """What planning again starts from: every face in the plan's region of its colour, the regions' records
    the plan's. A face on a border goes by its corners' mean colour, as the fit and the simulated world
    assign it, where segmentation voted by vertices: a few faces in a thousand may change sides."""
    plan = read_plan(builtin_plan)
    mesh = load_planned_mesh(plan, builtin_plan)
    seg = planned_segmentation(plan, mesh)
    assert seg.face_labels.shape == (len(mesh.faces),)
    assert seg.vertex_labels.shape == (len(mesh.vertices),)
    counts = np.bincount(seg.face_labels, minlength=len(plan.object.regions))
    assert np.allclose(counts, [r.faces for r in plan.object.regions], rtol=1e-3)
    assert [r.id for r in seg.regions] == [r.id for r in plan.object.regions]


def test_the_placement_record_is_in_the_plan_file(registered):
    _, placed_path, _, _ = registered
    data = json.loads(placed_path.read_text())
    record = data["object"]["placement"]
    assert set(record) >= {"status", "method", "date", "nominal_mesh_to_turntable", "photographs", "residual_px",
                           "se_shift_mm", "se_rotation_deg", "offset_shift_mm", "offset_turn_deg"}  # fmt: skip


def test_acquire_on_a_rig_warns_once_when_the_placement_was_never_measured(registered, tmp_path, capsys):
    """On a rig file (a real bench), a plan whose placement was never measured says so before anything
    moves; a registered plan does not, and neither does the simulated rig, whose object lies as planned."""
    plan_path, placed_path, _, _ = registered
    rig = tmp_path / "rig.toml"
    rig.write_text((resources.files("hlr_lab.data") / "sim-rig.toml").read_text())
    assert main(["acquire", "--plan", str(plan_path), "--rig", str(rig), "--dry-run"]) == 0
    printed = " ".join(capsys.readouterr().err.split())  # rich wraps the line to the terminal's width
    assert printed.count("placement assumed: the object is taken to lie exactly where the plan puts it") == 1
    assert main(["acquire", "--plan", str(placed_path), "--rig", str(rig), "--dry-run"]) == 0
    assert main(["acquire", "--plan", str(plan_path), "--sim", "--dry-run"]) == 0
    assert "assumed" not in capsys.readouterr().err


def test_the_placement_line_says_how_the_plan_knows_where_the_object_lies(registered):
    plan_path, placed_path, _, _ = registered
    assert placement_line(read_plan(plan_path)).startswith("assumed: ")
    line = placement_line(read_plan(placed_path))
    assert re.match(
        r"measured \S+ by outlines \(outline 0\.\d\d px RMS\): 14\.\d mm and -1(59\.[5-9]|60\.[0-4])° from",
        line,
    ), line


def test_a_misplaced_object_is_flagged_by_fit_and_at_the_top_of_the_report(builtin_plan, tmp_path, capsys):
    """The pebble 2.5 mm off the axis (2, −1.5 mm), hlr-lab believing the plan: its fit is off by 9–38 %
    (issue 22's table), and fit and report say why."""
    session = tmp_path / "s"
    assert main(["acquire", "--plan", str(builtin_plan), "--sim", "--object-offset", "2,-1.5,0", "--out",
                 str(session), "--speed-factor", "50"]) == 0  # fmt: skip
    capsys.readouterr()
    assert main(["fit", str(session)]) == 0
    printed = " ".join(capsys.readouterr().err.split())
    assert "misplaced: the photographs of 2 of 2 poses (p000, p001) do not show" in printed
    assert "run hlr-lab register" in printed
    alignment = json.loads((session / "fit-diagnostics.json").read_text())["alignment"]
    assert alignment["flagged"] == ["p000", "p001"]
    assert alignment["placement"] == "assumed"
    assert all(np.hypot(*p["outline"]["best_shift_px"]) >= 3 for p in alignment["poses"])
    assert main(["report", str(session)]) == 0
    page = (session / "report.html").read_text()
    assert page.index('class="misplaced"') < page.index("<h2>Materials</h2>")


def test_the_placed_plan_in_the_moved_world_fits_the_truth_and_is_not_flagged(registered):
    """End to end: ``acquire --register`` in the world whose object lies 12, −8 mm off and turned 200°, then
    fit: every region within the issue's targets (Rd 1 %, Rs 3 %, n 3 %; the pebble 2.5 mm off without
    registration: 8.7, 18, 38 %), and no pose flagged."""
    from worlds.truth import worst_errors_pct

    _, placed_path, _, session = registered
    assert json.loads((session / "session.json").read_text())["plan"]["path"] == str(placed_path.resolve())
    assert main(["fit", str(session), "--no-systematic"]) == 0
    alignment = json.loads((session / "fit-diagnostics.json").read_text())["alignment"]
    assert alignment["flagged"] == []
    assert alignment["placement"] == "measured"
    worst = worst_errors_pct(read_plan(placed_path), placed_path, None, session)
    assert worst["rd"] <= 1.0, worst
    assert worst["rs"] <= 3.0, worst
    assert worst["n"] <= 3.0, worst


def test_a_campaign_job_that_registers_resumes_with_its_placed_plan(registered, tmp_path):
    """register = true in a campaign: a session started registered resumes with the placed plan beside it,
    without photographing the object again, and is fitted and reported (the first night's registration is
    the command's: :func:`hlr_lab.registration.register_for_session`, the fixture's ``acquire --register``)."""
    from hlr_lab.campaign.runner import load_campaign, run_campaign
    from worlds.plan_world import job_links

    _, placed_path, photos, session = registered
    for source, name in ((session, "s0"), (photos, "s0-registration")):
        shutil.copytree(source, tmp_path / name)
    shutil.copy(placed_path, tmp_path / "s0-placed.json")
    frames = sorted((tmp_path / "s0-registration" / "frames").iterdir())
    night = tmp_path / "night.toml"
    night.write_text('[campaign]\nname = "n"\n[[job]]\nname = "j0"\nplan = "plan.json"\nout = "s0"\nsim = true\n'
                     "speed_factor = 50\nregister = true\n")  # fmt: skip
    shutil.copy(registered[0], tmp_path / "plan.json")
    results = run_campaign(load_campaign(night), links_for=job_links, calibrate=lambda job: None)
    assert [(r.name, r.status) for r in results] == [("j0", "done")], results
    assert sorted((tmp_path / "s0-registration" / "frames").iterdir()) == frames
    assert (tmp_path / "s0" / "report.html").is_file()


def test_acquire_register_refuses_a_dry_run_and_a_session_started_unregistered(
    finished_session, tmp_path, capsys
):
    session = tmp_path / "session"
    shutil.copytree(finished_session, session)
    plan = json.loads((session / "session.json").read_text())["plan"]["path"]
    assert main(["acquire", "--plan", plan, "--sim", "--register", "--dry-run"]) == 1
    assert "a dry run moves nothing, so it cannot register" in capsys.readouterr().err
    assert main(["acquire", "--plan", plan, "--sim", "--register", "--out", str(session)]) == 1
    assert "started without registering" in " ".join(capsys.readouterr().err.split())
    assert not (tmp_path / "session-registration").exists()


def test_a_registration_that_found_no_rig_can_be_run_again_in_its_folder(builtin_plan, tmp_path):
    """Devices that do not answer: the registration stops before anything moves, with no photograph and no
    placed plan; run again into the same folder, it is refused for the devices again — not for the folder."""
    from hlr_lab.errors import HlrLabError
    from hlr_lab.instrument.devices import Links
    from hlr_lab.registration import register_plan
    from hlr_lab.registration.capture import REGISTRATION_PLAN

    folder, placed = tmp_path / "photos", tmp_path / "placed.json"
    nowhere = Links(gantry=str(tmp_path / "no-such-port"), stage="127.0.0.1:9", camera="127.0.0.1:9")
    for _ in range(2):
        with pytest.raises(HlrLabError) as err:
            register_plan(builtin_plan, sim_rig(), folder, placed, links=nowhere)
        assert "turntable on 127.0.0.1:9: cannot connect" in str(err.value)
        assert (folder / REGISTRATION_PLAN).is_file()
        assert not list(folder.glob("frames/*.png"))
        assert not placed.exists()
