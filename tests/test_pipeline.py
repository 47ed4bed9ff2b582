"""The measurement driven from code (:mod:`hlr_lab.pipeline`), as a program other than the command line
would: object → plan → acquire on the simulated rig → fit → report → export, each step's files on disk."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hlr_lab.errors import InputError
from hlr_lab.formats.plan import read_plan, write_plan
from hlr_lab.formats.regions import write_regions
from hlr_lab.instrument.devices import Links
from hlr_lab.object.segment import segment
from hlr_lab.pipeline import acquire_plan, export_materials, fit_into, load_object, plan_object, report_into
from hlr_lab.planning.planner import PlanSettings
from hlr_lab.rig.file import rig_of_snapshot
from sim.rig import SimRig
from tests.renderer_guard import require_renderer
from worlds.plan_world import sim_scene, world_geometry

require_renderer(module_level=True)


def test_the_steps_run_from_code_and_leave_their_files(tmp_path, rig):
    """builtin:pebble on the simulated rig: every region's Rd within 1 %, Rs and n within 5 % of the truth
    (the demo's tolerances: the simulated world is the rig file, so only noise is left), and the report
    and the three exports written."""
    mesh = load_object("builtin:pebble")
    seg = segment(mesh)
    write_regions(tmp_path / "regions.json", mesh, seg, mesh_name="builtin:pebble", regions_requested=None)
    plan, result = plan_object(
        mesh, seg, rig, PlanSettings(), mesh_spec="builtin:pebble", plan_folder=tmp_path
    )
    assert not result.uncovered
    plan_path = tmp_path / "plan.json"
    write_plan(plan_path, plan)

    steps = []
    with SimRig(scene=sim_scene(plan, plan_path, None), speed_factor=40, **world_geometry(rig)) as world:
        e = world.endpoints
        outcome = acquire_plan(plan_path, rig, tmp_path / "session", links=Links(e.dynamixel, e.modbus, e.camera),
                               progress=steps.append)  # fmt: skip
    assert outcome.taken == sum(len(p.exposures_s) for p in plan.poses)
    assert (steps[-1].action, steps[-1].index) == ("done", len(plan.poses) - 1)

    fitted = fit_into(tmp_path / "session")
    assert json.loads((tmp_path / "session" / "materials.json").read_text())["regions"]
    truth = dict(
        zip((r.id for r in plan.object.regions), sim_scene(plan, plan_path, None).materials, strict=True)
    )
    for entry in fitted.materials.regions:
        true = truth[entry.id]
        assert np.abs(np.array(entry.rd) / true.rd - 1).max() < 0.01
        assert np.abs(np.array(entry.rs) / true.rs - 1).max() < 0.05
        assert abs(entry.n / true.n - 1) < 0.05

    report, figures, size = report_into(tmp_path / "session")
    assert report.stat().st_size == size > 0
    assert set(figures.psnr_db) == {p.id for p in plan.poses}
    for fmt, name in (("obj", "o.obj"), ("gltf", "o.glb"), ("mitsuba", "scene")):
        written, stand_ins = export_materials(tmp_path / "session" / "materials.json", mesh, fmt, tmp_path / name,
                                   regions_path=tmp_path / "regions.json")  # fmt: skip
        assert written
        assert all(p.exists() for p in written)
        assert stand_ins == []  # every region was fitted


def test_acquiring_needs_a_lamp_and_says_so_before_anything_opens(tmp_path, rig, builtin_plan):
    """A rig file without [lamp]: refused naming the section; no session folder is made, no device is
    opened (the links point nowhere: opening one would fail differently)."""
    snapshot = rig.file.model_dump(mode="json", exclude_none=True)
    snapshot.pop("lamp")
    lampless = rig_of_snapshot(snapshot, "lampless.toml")
    with pytest.raises(InputError, match="lamp"):
        acquire_plan(
            builtin_plan, lampless, tmp_path / "session", links=Links("/dev/nonexistent", "tcp://127.0.0.1:9")
        )
    assert not (tmp_path / "session").exists()


def test_exports_are_refused_with_the_wrong_suffix(tmp_path, builtin_plan):
    mesh = load_object("builtin:pebble")
    with pytest.raises(InputError, match=r"\.glb"):
        export_materials(tmp_path / "none.json", mesh, "gltf", tmp_path / "o.obj")
    with pytest.raises(InputError, match="texture"):
        load_object("builtin:pebble", tmp_path / "t.png")
    assert read_plan(builtin_plan).poses
