"""Where the object really lies: the simulated world's ``placed`` and ``--object-offset`` (the plan is
hlr-lab's belief, never the world's)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from hlr_lab.cli.main import main
from hlr_lab.formats.plan import read_plan
from hlr_lab.formats.planned_object import mesh_to_turntable
from hlr_lab.geometry.camera import Camera
from sim.render.scene import SceneError, load_scene, pose_matrix
from worlds.plan_world import ObjectOffset, sim_scene


def _scene_file(folder: Path, placed: str | None) -> Path:
    mesh = trimesh.creation.box(extents=(0.04, 0.03, 0.02))
    mesh.visual.vertex_colors = np.tile([200, 60, 40, 255], (len(mesh.vertices), 1))
    mesh.export(folder / "box.ply")
    text = '[object]\nmesh = "box.ply"\n' + (f"placed = {placed}\n" if placed else "")
    text += "\n[[region]]\ncolor = [200, 60, 40]\nrd = [0.5, 0.2, 0.1]\nrs = [0.2, 0.2, 0.2]\nn = 40.0\n"
    path = folder / "scene.toml"
    path.write_text(text)
    return path


def test_a_scene_file_says_where_the_object_lies(tmp_path):
    placed = "{ translation_m = [0.002, -0.0015, 0.01], rotation_deg = [1, 2, 200] }"
    spec = load_scene(_scene_file(tmp_path, placed))
    assert spec.placed
    np.testing.assert_allclose(spec.mesh_to_turntable, pose_matrix((0.002, -0.0015, 0.01), (1, 2, 200)))
    # R = Rz·Ry·Rx, then the translation: a turn about z alone moves +x to (cos, sin)
    np.testing.assert_allclose(
        pose_matrix((0, 0, 0), (0, 0, 30))[:3, 0], [np.cos(np.pi / 6), 0.5, 0], atol=1e-12
    )
    assert not load_scene(_scene_file(tmp_path, None)).placed


@pytest.mark.parametrize(
    ("placed", "names"),
    [
        ("{ translation = [0, 0, 0], rotation_deg = [0, 0, 0] }", "object.placed.translation"),
        ("{ translation_m = [0, 0], rotation_deg = [0, 0, 0] }", "object.placed.translation_m"),
        ("{ translation_m = [0, 0, 0], rotation_deg = [0, 0, nan] }", "object.placed.rotation_deg"),
        ('"here"', "object.placed"),
    ],
)
def test_a_broken_placement_is_refused_naming_its_field(tmp_path, placed, names):
    with pytest.raises(SceneError, match=f"{names}:"):
        load_scene(_scene_file(tmp_path, placed))


def test_the_old_pose_key_is_refused_naming_placed(tmp_path):
    path = _scene_file(tmp_path, None)
    path.write_text(
        path.read_text().replace(
            "\n\n", "\npose = { translation = [0, 0, 0], rotation_deg = [0, 0, 0] }\n\n", 1
        )
    )
    with pytest.raises(SceneError, match=r"object\.pose: no longer read.*object\.placed"):
        load_scene(path)


def test_the_world_puts_the_object_where_the_scene_says_never_where_the_plan_says(builtin_plan):
    plan_path = builtin_plan
    plan = read_plan(plan_path)
    believed = mesh_to_turntable(plan)
    np.testing.assert_allclose(sim_scene(plan, plan_path, None).mesh_to_turntable, believed)
    offset = ObjectOffset.from_option((2.0, -1.5, 3.0))
    moved = sim_scene(plan, plan_path, None, offset).mesh_to_turntable
    np.testing.assert_allclose(moved, pose_matrix((0.002, -0.0015, 0), (0, 0, 3)) @ believed)
    # a point on the axis goes where the offset says; the object is turned 3° about the axis
    on_axis = np.linalg.solve(believed, [0, 0, 0.01, 1])
    np.testing.assert_allclose((moved @ on_axis)[:3], [0.002, -0.0015, 0.01], atol=1e-12)
    turn = moved[:3, :3] @ believed[:3, :3].T
    assert np.degrees(np.arctan2(turn[1, 0], turn[0, 0])) == pytest.approx(3.0)


def test_a_moved_object_is_photographed_where_it_lies(builtin_plan):
    """The renderer draws the object where the world says: its silhouette's centre moves by the projected
    offset (within 0.3 px: a 2 mm move is 7 px on this camera)."""
    from tests.cameras import half_size_camera
    from tests.renderer_guard import require_renderer

    require_renderer()
    from sim.render.camera import CameraSpec
    from sim.render.renderer import Renderer

    plan_path = builtin_plan
    plan = read_plan(plan_path)
    cam = half_size_camera()
    spec = CameraSpec(cam.matrix, cam.distortion, cam.rotation, cam.translation, cam.width, cam.height)
    light = np.array([0.0, -0.5, 0.5])

    def centroid(scene) -> np.ndarray:
        image = Renderer(scene, spec, spp=4).render(0.0, light).sum(axis=2)
        rows, cols = np.nonzero(image > 0)
        return np.array([cols.mean(), rows.mean()])

    still = sim_scene(plan, plan_path, None)
    moved = sim_scene(plan, plan_path, None, ObjectOffset(0.002, 0.0, 0.0))
    shift = centroid(moved) - centroid(still)
    expected = _projected_shift(
        cam, still.vertices @ still.mesh_to_turntable[:3, :3].T + still.mesh_to_turntable[:3, 3]
    )
    np.testing.assert_allclose(shift, expected, atol=0.3)


def _projected_shift(cam: Camera, points: np.ndarray) -> np.ndarray:
    """(2,) px: how far a 2 mm move along +x carries the projection of the points' centre."""
    centre = points.mean(axis=0, keepdims=True)
    uv0, _ = cam.project(centre)
    uv1, _ = cam.project(centre + np.array([0.002, 0.0, 0.0]))
    return (uv1 - uv0)[0]


def test_object_offset_is_for_the_simulated_world_and_three_numbers(builtin_plan, capsys):
    plan_path = builtin_plan
    assert main(["acquire", "--plan", str(plan_path), "--rig", "x.toml", "--object-offset", "1,2,3"]) == 1
    assert "--object-offset" in capsys.readouterr().err
    assert main(["acquire", "--plan", str(plan_path), "--sim", "--object-offset", "1,2"]) == 2
    assert "3 finite numbers" in capsys.readouterr().err
