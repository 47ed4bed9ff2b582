"""fit --radiance: each pose's merged radiance as an OpenEXR file, read back by OpenEXR and by FFmpeg's own
EXR decoder (PyAV), equal to the merge the fit used."""

import json
import os

import numpy as np
import pytest

from hlr_lab.cli.main import main
from hlr_lab.reflectance.radiance_file import RadianceHeader, read_radiance, write_radiance
from hlr_lab.reflectance.session_fit import open_session, placed_mesh, view_pose, view_radiance


def second_reader(path) -> np.ndarray:
    """(H, W, 3) float32 as FFmpeg's EXR decoder reads the file (code that is not OpenEXR's)."""
    import av

    with av.open(str(path)) as container:
        frame = next(container.decode(video=0))
        assert frame.format.name == "gbrpf32le"  # planar float: no conversion on the way
        return frame.to_ndarray()


def header(**changes) -> RadianceHeader:
    fields = dict(pose="p007", turntable_deg=-35.25, lamp_m=(0.1, -0.2, 0.3), lamp_power=1.25,
                  exposures_s=(0.004, 0.032), gains_db=(0.0, 6.0),
                  camera_matrix=((1200.0, 0.0, 640.5), (0.0, 1201.0, 480.25), (0.0, 0.0, 1.0)),
                  distortion=(-0.1, 0.02, 0.001, -0.002, 0.0))  # fmt: skip
    return RadianceHeader(**{**fields, **changes})


def test_a_radiance_file_round_trips_bit_exact_with_its_header(tmp_path):
    rng = np.random.default_rng(3)
    value = rng.lognormal(-2, 2, (48, 64, 3)).astype(np.float32)  # an HDR range: 1e-4 to 10⁰ and beyond
    usable = rng.random((48, 64)) > 0.1
    value[~usable] = np.nan  # the merge's unusable pixels
    fit = usable & (rng.random((48, 64)) > 0.5)
    write_radiance(tmp_path / "p007.exr", value, usable, fit, header())
    back = read_radiance(tmp_path / "p007.exr")
    assert back.header == header()
    np.testing.assert_array_equal(back.value[usable], value[usable])
    assert not back.value[~usable].any()  # written as 0, the mask says why
    np.testing.assert_array_equal(back.usable, usable)
    np.testing.assert_array_equal(back.fit, fit)
    np.testing.assert_array_equal(second_reader(tmp_path / "p007.exr"), back.value)
    assert [p.name for p in tmp_path.iterdir()] == ["p007.exr"]  # no temporary left


def test_a_file_that_is_not_a_radiance_file_is_named(tmp_path):
    import OpenEXR

    plain = {
        "R": np.zeros((4, 4), np.float32),
        "G": np.zeros((4, 4), np.float32),
        "B": np.zeros((4, 4), np.float32),
    }
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, plain) as f:
        f.write(str(tmp_path / "other.exr"))
    with pytest.raises(ValueError, match=r"other\.exr: not an hlr-lab radiance file"):
        read_radiance(tmp_path / "other.exr")


@pytest.mark.slow
def test_fit_writes_each_poses_radiance_as_the_fit_merged_it(tmp_path, capsys):
    """builtin:pebble's plan on the simulated rig, fitted with --radiance: a file per pose, whose values are
    the in-memory merge's bit for bit, whose fit mask holds as many pixels as the fit took from the pose,
    and whose header is the pose's (its sidecars' exposures, the measured turntable angle and lamp), linked
    from the report; a radiance file or folder that is a symbolic link is refused before anything is written."""
    from tests.renderer_guard import require_renderer

    require_renderer()
    plan, session = tmp_path / "plan.json", tmp_path / "session"
    assert main(["plan", "--mesh", "builtin:pebble", "--sim", "-o", str(plan)]) == 0
    assert main(["acquire", "--plan", str(plan), "--sim", "--out", str(session), "--speed-factor", "40"]) == 0
    capsys.readouterr()

    (session / "radiance").mkdir()
    (session / "radiance" / "p000.exr").symlink_to(tmp_path / "elsewhere.exr")
    assert main(["fit", str(session), "--radiance", "--no-systematic"]) == 1
    assert "p000.exr" in capsys.readouterr().err
    assert not (session / "materials.json").exists()
    assert not (tmp_path / "elsewhere.exr").exists()
    (session / "radiance" / "p000.exr").unlink()
    (session / "radiance").rmdir()
    (tmp_path / "away").mkdir()
    (session / "radiance").symlink_to(tmp_path / "away", target_is_directory=True)
    assert main(["fit", str(session), "--radiance", "--no-systematic"]) == 1
    assert "symbolic link" in capsys.readouterr().err
    assert not list((tmp_path / "away").iterdir())
    (session / "radiance").unlink()

    assert main(["fit", str(session), "--radiance", "--no-systematic"]) == 0
    assert "radiance" in capsys.readouterr().err
    s = open_session(session)
    mesh = placed_mesh(s)
    diagnostics = json.loads((session / "fit-diagnostics.json").read_text())
    assert sorted(os.listdir(session / "radiance")) == sorted(f"{v.pose}.exr" for v in s.views)
    for view in s.views:
        back = read_radiance(session / "radiance" / f"{view.pose}.exr")
        merged = view_radiance(s, view, mesh)
        np.testing.assert_array_equal(back.usable, merged.usable)
        np.testing.assert_array_equal(back.value[merged.usable], merged.value[merged.usable])
        taken = sum(d.get("samples_per_pose", {}).get(view.pose, 0) for d in diagnostics["regions"])
        assert taken > 1000
        assert back.fit.sum() == taken
        assert not (back.fit & ~back.usable).any()
        pose = view_pose(s, view)
        assert back.header.pose == view.pose
        assert back.header.turntable_deg == pytest.approx(pose.turntable_deg, abs=1e-12)
        np.testing.assert_allclose(back.header.lamp_m, pose.light_world, atol=1e-12)
        assert back.header.exposures_s == tuple(
            float(view.sidecars[e["file"]]["exposure_s"]) for e in view.frames
        )
        np.testing.assert_allclose(back.header.camera_matrix, s.rig.camera.matrix, atol=1e-12)
    first = session / "radiance" / f"{s.views[0].pose}.exr"
    np.testing.assert_array_equal(second_reader(first), read_radiance(first).value)

    # the report links them, from wherever it is written
    assert main(["report", str(session)]) == 0
    assert f'href="radiance/{s.views[0].pose}.exr"' in (session / "report.html").read_text()
    (tmp_path / "elsewhere").mkdir()
    assert main(["report", str(session), "-o", str(tmp_path / "elsewhere" / "r.html")]) == 0
    assert (
        f'href="../session/radiance/{s.views[0].pose}.exr"' in (tmp_path / "elsewhere" / "r.html").read_text()
    )
