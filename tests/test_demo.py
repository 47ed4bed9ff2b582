"""``hlr-lab demo`` end to end on the simulated rig, and its report opened in a headless browser."""

import re

import cv2

from hlr_lab.cli.main import main
from hlr_lab.formats.plan import read_plan
from tests.browser import dom_after_load, screenshot
from tests.renderer_guard import require_renderer

require_renderer(module_level=True)


def test_the_demo_measures_the_builtin_object_and_reports_it(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--speed-factor", "40"]) == 0
    printed = capsys.readouterr().err
    for written in ("regions.json", "plan.json", "session/materials.json", "session/report.html",
                    "export/object.obj", "export/object.glb", "export/mitsuba/scene.xml"):  # fmt: skip
        assert (out / written).is_file(), written
    # the truth table: per region Rd, Rs and n errors (%), within the 1 / 5 / 5 %
    table = printed[printed.index("fitted against the simulated truth") :]
    rows = re.findall(r"│\s+(\d+) │[^│]+│[^│]+│\s+([\d.]+) │\s+([\d.]+) │[^│]+│\s+([\d.]+) │", table)
    assert len(rows) == 4
    for _, rd, rs, n in rows:
        assert float(rd) < 1.0
        assert float(rs) < 5.0
        assert float(n) < 5.0
    assert "report: " in printed

    # again into the same folder: refused, nothing touched
    assert main(["demo", "--out", str(out)]) == 1
    assert "not empty" in capsys.readouterr().err


def test_the_report_opens_offline_with_its_images_and_tables(tmp_path):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--speed-factor", "40"]) == 0
    page = out / "session" / "report.html"
    text = page.read_text()
    assert not re.search(
        r"""(src|href|url)\s*[=(]\s*["']?(https?:)?//""", text
    )  # nothing to fetch: opens offline
    dom = dom_after_load(page)
    images = text.count("<img ")
    assert images >= 6  # captured, rendered back and error map per pose (2 poses)
    assert f'data-images-loaded="{images}"' in dom  # every embedded image decoded
    assert dom.count("<table") >= 3  # materials, plan, runs
    assert "PSNR" in dom
    assert "assumed: the object is taken to lie exactly where the plan puts it" in text  # never registered

    png = tmp_path / "report.png"
    screenshot(page, png)
    shot = cv2.imread(str(png))[..., ::-1]
    assert shot.shape[:2] == (2400, 1200)
    colourful = (shot.max(axis=-1).astype(int) - shot.min(axis=-1)) > 60  # the object's colours, not text
    assert colourful.mean() > 0.02
    assert shot.std() > 30


def test_the_demo_on_a_scene_file_compares_with_its_materials(tmp_path, capsys):
    """--scene: the scene's mesh is planned and measured, and the truth is the scene's own materials. The
    mesh is stored as a scan often is, y up and in millimetres: --up y --scale 0.001 stand it as the
    plan's pebble stands (lying down, it would be measured from below)."""
    import numpy as np
    import trimesh

    from hlr_lab.object.procedural import pebble

    body = pebble().mesh
    alpha = np.full((len(body.vertices), 1), 255, np.uint8)
    y_up_mm = 1000 * body.vertices[:, [0, 2, 1]] * [1, 1, -1]  # (x, y, z) → (x, z, −y): its up is +y
    trimesh.Trimesh(
        y_up_mm, body.faces, vertex_colors=np.hstack([body.vertex_colours, alpha]), process=False
    ).export(tmp_path / "pebble.ply")
    colours = np.unique(body.vertex_colours, axis=0)
    regions = "".join(
        f"\n[[region]]\ncolor = {[int(c) for c in colour]}\nrd = [0.5, 0.4, 0.3]\nrs = [0.2, 0.2, 0.2]\nn = 50.0\n"
        for colour in colours
    )
    scene = tmp_path / "scene.toml"
    scene.write_text(f'[object]\nmesh = "pebble.ply"\n\n[light]\ntype = "point"\npower = 1.0\n{regions}')
    out = tmp_path / "demo"
    command = [
        "demo",
        "--scene",
        str(scene),
        "--up",
        "y",
        "--scale",
        "0.001",
        "--out",
        str(out),
        "--speed-factor",
        "40",
    ]
    assert main(command) == 0
    placed = read_plan(out / "plan.json").object
    assert (placed.up, placed.scale) == ("y", 0.001)
    printed = capsys.readouterr().err
    table = printed[printed.index("fitted against the simulated truth") :]
    rows = re.findall(r"│\s+(\d+) │[^│]+│[^│]+│\s+([\d.]+) │\s+([\d.]+) │[^│]+│\s+([\d.]+) │", table)
    assert len(rows) == len(colours)
    # against the scene's materials (not the default world's, which differ by far more than 1 %)
    assert all(float(rd) < 1.0 and float(rs) < 5.0 for _, rd, rs, _ in rows)


def test_the_demo_says_what_its_fit_says_a_misplaced_object_first(tmp_path, capsys):
    """The object 7.7 mm off and turned 27°, hlr-lab not told: the demo prints the fit's lines beside its
    table as ``fit`` does (the systematic terms left out, the misplacement), and the region whose pixels read
    darker than black is told to register the object, not to check the black level, which the exposure
    brackets show is right."""
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--object-offset", "6.5,-4.2,27", "--speed-factor", "40"]) == 0
    printed = " ".join(capsys.readouterr().err.split())
    assert "systematic: the object's placement was assumed, not measured" in printed
    assert "misplaced: the photographs of 2 of 2 poses (p000, p001) do not show" in printed
    notes = re.findall(r"region \d+: (.*?) \(no entry written\)", printed)
    assert notes, printed
    for note in notes:
        assert (
            "darker than black: the photographs of 2 pose(s) show the object off where the plan puts it"
            in note
        )
        assert "black_level_dn" not in note
