"""What the commands show (hlr_lab.display) and the operator's calibration targets, as library calls."""

import contextlib

from rich.console import Console

from calibration.operator import OperatorTargets
from hlr_lab.acquisition.poses import Outcome
from hlr_lab.campaign.runner import JobResult
from hlr_lab.display.acquire import run_table
from hlr_lab.display.campaign import campaign_table
from hlr_lab.display.doctor import findings_table
from hlr_lab.display.materials import materials_table
from hlr_lab.display.plan import MAX_POSE_COLUMNS, coverage_table, plan_summary
from hlr_lab.formats.materials import MaterialsFile
from hlr_lab.instrument.devices import Links
from hlr_lab.instrument.doctor import Finding
from hlr_lab.object.procedural import pebble
from hlr_lab.object.segment import segment
from hlr_lab.planning.geometry import placement
from hlr_lab.planning.planner import PlanSettings, plan_lights
from hlr_lab.rig.file import sim_rig


def shown(item) -> str:
    console = Console(record=True, width=240, color_system=None)
    console.print(item)
    return console.export_text()


def test_the_coverage_table_sums_the_lights_beyond_its_columns_and_says_why_a_region_is_short(tmp_path):
    mesh = pebble(subdivisions=3).mesh
    seg = segment(mesh)
    placed = mesh.transformed(placement(mesh))
    settings = PlanSettings(min_samples=1e9, max_lights=MAX_POSE_COLUMNS + 2, views_deg=[0.0], spacing_deg=2.0,
                            count="vertices", compare_criteria=False)  # fmt: skip
    result = plan_lights(placed, seg, sim_rig(), settings)
    assert len(result.lights) == MAX_POSE_COLUMNS + 2  # M is out of reach: the planner stops at its limit
    text = shown(coverage_table(result, seg))
    assert "…" in text
    assert f"p{MAX_POSE_COLUMNS - 1:03d}" in text
    assert f"p{MAX_POSE_COLUMNS:03d}" not in text
    cells = [[c.strip() for c in line.split("│")[1:-1]] for line in text.splitlines()]
    rows = {row[0]: row for row in cells if row and row[0].isdigit()}
    for r in seg.regions:  # every region's row: its totals, and "no" with the planner's own reason
        assert rows[str(r.id)][-3] == f"{result.coverage[r.id]:.0f}"
        assert rows[str(r.id)][-2] == f"{result.diffuse[r.id]:.0f}"
        assert rows[str(r.id)][-1].startswith("no: " + result.uncovered[r.id][:20])
    lines = plan_summary(result, tmp_path / "plan.json")
    assert lines[0].startswith(f"{len(result.lights)} lights over 1 turntable view(s) 0°")
    assert f"{seg.n_regions} region(s) cannot get their 1e+09 samples" in lines[-2]
    assert lines[-1] == f"wrote {tmp_path / 'plan.json'}"


def test_the_materials_table_gives_the_reason_of_an_unmeasured_lobe():
    common = {"vertices": 10, "rd_se": [0.001, 0.002, 0.003], "residual_rms": 0.01, "estimator": "robust"}
    measured = {"id": 0, "color": [200, 100, 50], "rd": [0.5, 0.4, 0.3], "specular": "measured",
                "rs": [0.2, 0.2, 0.2], "rs_se": [0.01, 0.01, 0.01], "n": 41.26, "n_se": 0.4, "theta_c_deg": 12.0,
                "pixels": {"diffuse": 900, "highlight": 120}}  # fmt: skip
    unmeasured = {"id": 3, "color": [20, 20, 20], "rd": [0.1, 0.1, 0.1], "specular": "unmeasured",
                  "reason": "12 highlight pixels, 200 needed", "theta_c_deg": 10.0,
                  "pixels": {"diffuse": 500, "highlight": 12}}  # fmt: skip
    header = {"format": "hlr-lab.materials", "version": 1, "model": "blinn-phong"}
    materials = MaterialsFile.model_validate(
        {**header, "regions": [{**common, **measured}, {**common, **unmeasured}]}
    )
    text = shown(materials_table(materials))
    assert "(± standard error)" in text
    row = next(line for line in text.splitlines() if "0.5000±0.0010" in line)
    assert "41.26±0.40" in row
    assert "900 / 120" in row
    row = next(line for line in text.splitlines() if "0.1000±0.0010" in line)
    assert "unmeasured" in row
    assert "12 highlight pixels, 200 needed" in row
    # with the systematic part: a third ±, and the title says which is which; a narrow terminal folds
    systematic = {"rd_sys": [0.004, 0.003, 0.002], "rs_sys": [0.005, 0.005, 0.005], "n_sys": 1.5}
    materials = MaterialsFile.model_validate({**header, "regions": [{**common, **measured, **systematic}]})
    text = shown(materials_table(materials))
    assert "(± statistical ± systematic)" in text
    row = next(line for line in text.splitlines() if "0.5000±0.0010±0.0040" in line)
    assert "41.26±0.40±1.50" in row
    assert "0.2000±0.0100±0.0050" in row
    narrow = Console(record=True, width=80, color_system=None)
    narrow.print(materials_table(materials))
    assert "…" not in narrow.export_text()


def test_the_run_table_counts_the_lamp_on_the_white_reference_only_when_there_is_one(tmp_path):
    plain = shown(run_table(Outcome(taken=7, retaken=["a", "b"], duration_s=3.25), tmp_path))
    assert "frames taken" in plain
    assert "│ frames retaken (missing or changed) │     2 │" in plain
    assert "3.2 s" in plain
    assert "white reference" not in plain
    beside = shown(run_table(Outcome(reference_poses=5, reference_measured=4), tmp_path))
    assert "4 of 5 poses" in beside


def test_findings_and_the_night_show_every_row():
    findings = [Finding("servo 1 (azimuth)", "ok", "ready"), Finding("lamp", "problem", "no answer [x]")]
    text = shown(findings_table("rig", findings))
    assert "servo 1 (azimuth)" in text
    assert "problem" in text
    assert "no answer [x]" in text  # escaped: [x] is no markup
    night = shown(campaign_table("night", [JobResult("a", "done", 1), JobResult("b", "skipped", 2, "bus")]))
    assert "campaign night" in night
    assert "skipped" in night
    assert "bus" in night


def test_the_operator_is_asked_for_each_target_and_the_rig_files_own_links_are_used():
    asked: list[str] = []
    targets = OperatorTargets(asked.append)
    with contextlib.ExitStack() as stack:
        links, turn = targets.board(stack, sim_rig())
        turn(0)
        turn(1)
        ball = targets.mirror_ball(stack, sim_rig())
        white = targets.white_reference(stack, sim_rig())
    for links_of_target in (links, ball, white):  # the rig file's own links: nothing simulated
        assert links_of_target == Links()
    assert asked == [
        "Put the board on the wedge's first face, facing the camera. Ready?",
        "Put the board on the wedge's other face (turn the wedge over), facing the camera. Ready?",
        "Put the mirror ball on the plate where the rig file says. Ready?",
        "Put the white reference on the plate where the rig file says. Ready?",
    ]
