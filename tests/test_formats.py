import json
from pathlib import Path

import numpy as np
import pytest

from hlr_lab.errors import InputError
from hlr_lab.files import atomic_write_bytes, atomic_write_text
from hlr_lab.formats.plan import read_plan
from hlr_lab.formats.regions import read_regions, write_regions
from hlr_lab.geometry.sphere import rotation_z
from hlr_lab.object.procedural import pebble
from hlr_lab.object.segment import segment
from hlr_lab.rig.file import ARUCO_DICTIONARIES, load_rig

SIM_RIG = Path(__file__).resolve().parents[1] / "hlr_lab" / "data" / "sim-rig.toml"


def test_plan_round_trip_and_skeleton(plan_file):
    path, result, obj, m = plan_file
    plan = read_plan(path)
    raw = json.loads(path.read_text())
    assert raw["format"] == "hlr-lab.plan"
    assert raw["version"] == 1
    assert set(raw) >= {"object", "parameters", "poses", "coverage", "uncovered"}
    assert set(raw["parameters"]) >= {"theta_c_deg", "min_samples", "sphere_radius_m", "count", "criterion"}
    assert len(plan.poses) == len(result.lights)
    for pose, light in zip(plan.poses, result.lights, strict=True):
        # position_mesh_m is in the mesh's own frame: mapping it through the placement and the turntable
        # angle gives the world position
        p_mesh = np.append(pose.light.position_mesh_m, 1.0)
        world = (rotation_z(np.radians(pose.turntable_deg)) @ m @ p_mesh)[:3]
        np.testing.assert_allclose(world, pose.light.position_m, atol=2e-6)
        assert sum(pose.expected.values()) == pytest.approx(light.expected.sum(), abs=0.5)
    assert plan.object.sha256 == obj.mesh.sha256


def _mutated(path: Path, tmp_path: Path, change) -> Path:
    data = json.loads(path.read_text())
    change(data)
    out = tmp_path / "bad.json"
    out.write_text(json.dumps(data))
    return out


@pytest.mark.parametrize(
    ("change", "field", "message"),
    [
        (lambda d: d.update(format="something.else"), "format", "not an hlr-lab.plan"),
        (lambda d: d.update(version=2), "version", "upgrade"),
        (lambda d: d.pop("poses"), "poses", "required"),
        (lambda d: d["poses"][0].update(exposures_s=[]), "poses[0].exposures_s", "at least 1"),
        (lambda d: d["parameters"].update(count="photons"), "parameters.count", "pixels"),
    ],
)
def test_malformed_plans_name_the_field(plan_file, tmp_path, change, field, message):
    bad = _mutated(plan_file[0], tmp_path, change)
    with pytest.raises(InputError, match=message) as err:
        read_plan(bad)
    assert field in str(err.value)
    assert str(bad) in str(err.value)


def test_not_json(tmp_path):
    p = tmp_path / "plan.json"
    p.write_text("{ not json")
    with pytest.raises(InputError, match="not valid JSON"):
        read_plan(p)


def test_regions_round_trip_and_mesh_check(tmp_path):
    obj = pebble(subdivisions=3)
    seg = segment(obj.mesh, split_connected=True)
    path = tmp_path / "regions.json"
    write_regions(path, obj.mesh, seg, mesh_name="builtin:pebble", regions_requested=None)
    back = read_regions(path, obj.mesh)
    assert np.array_equal(back.vertex_labels, seg.vertex_labels)
    assert np.array_equal(back.face_labels, seg.face_labels)
    assert back.split_connected
    for a, b in zip(back.regions, seg.regions, strict=True):
        assert (a.id, a.material, a.colour, a.vertices, a.faces) == (
            b.id,
            b.material,
            b.colour,
            b.vertices,
            b.faces,
        )
        assert a.area_m2 == pytest.approx(b.area_m2, abs=1e-9)
    other = pebble(subdivisions=2).mesh
    with pytest.raises(InputError, match="another mesh"):
        read_regions(path, other)
    data = json.loads(path.read_text())
    data["regions"] = []
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match=r"regions\.json: regions: List should have at least 1 item"):
        read_regions(path, obj.mesh)


def test_atomic_write_keeps_the_old_file_on_failure(tmp_path):
    p = tmp_path / "plan.json"
    atomic_write_text(p, "old")
    with pytest.raises(TypeError):
        atomic_write_bytes(p, "text is not bytes")  # fails inside the write, after the temporary exists
    assert p.read_text() == "old"
    assert [f.name for f in tmp_path.iterdir()] == ["plan.json"]  # no temporary left behind


def test_sim_rig_file_loads():
    rig = load_rig(SIM_RIG)
    assert rig.gantry.arm_radius == 0.30
    assert rig.camera.width == 1280
    np.testing.assert_allclose(rig.camera.centre, [0.0, -0.62, 0.30])


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("elevation_limits_deg = [-10.0, 80.0]", "elevation_limits_deg = [80.0, -10.0]", "gantry"),
        ("arm_radius_m = 0.30", "arm_radius_m = -1", "gantry.arm_radius_m"),
        ("[turntable]", "[turntable]\nspeed = 3", "turntable.speed"),
        ("[turntable]", "[turntable]\nregisters = {bogus = 3}", "turntable.registers"),
        ("coil = 0", "coil = -1", "lamp.coil"),
        ('format = "hlr-lab.rig"', 'format = "hlr-lab.plan"', "rig.format"),
        ("width = 1280", "width = 1280 1280", "not valid TOML"),
        ("servo_ids = [1, 2]", "servo_ids = [3, 3]", "two different servo IDs"),
        ("servo_ids = [1, 2]", "servo_ids = [1, 300]", "gantry.servo_ids"),
        ("directions = [1, 1]", "directions = [0, 1]", "gantry.directions"),
        ("ticks_per_rev = 4096", "ticks_per_rev = 0", "gantry.ticks_per_rev"),
        ("zero_ticks = [2048, 1024]", "zero_ticks = [100, 1024]", "azimuth_limits_deg map to servo ticks"),
        ("steps_per_degree = 100.0", "steps_per_degree = -1", "turntable.steps_per_degree"),
        ("limits_deg = [-180.0, 180.0]", "limits_deg = [180.0, -180.0]", "the lower limit 180 must"),
        ("arm_radius_m = 0.30", 'arm_radius_m = "0.30"', "arm_radius_m: Input should be a valid number"),
        ("ticks_per_rev = 4096", "ticks_per_rev = true", "gantry.ticks_per_rev"),
        ("matrix = [[2400.0", "matrix = [[0.0", "camera: matrix must be a camera matrix"),
        ("matrix = [[2400.0, 0.0", "matrix = [[2400.0, 0.5", "camera: matrix must be a camera matrix"),
        ("[0.0, 2400.0, 476.0]", "[0.0, 2400.0, 4760.0]", "the principal point"),
        ("baudrate = 1000000", "baudrate = 1234", "gantry.baudrate: 1234 bps is not a speed an X-series"),
        ("profile_velocity = 100", "profile_velocity = 40000", "gantry.profile_velocity"),
        ('dictionary = "DICT_4X4_50"', 'dictionary = "DICT_9X9_50"', "board: dictionary 'DICT_9X9_50'"),
        ('dictionary = "DICT_4X4_50"', 'dictionary = "DICT_APRILTAG_16h5"', "than DICT_APRILTAG_16h5's 30"),
        ("[turntable]", '[turntable]\naddress = "10.0.0.2:99999"', "address: '10.0.0.2:99999' is not"),
        ("[turntable]", '[turntable]\naddress = "tcp://10.0.0.2"', "turntable.address"),
        ("[camera]", '[camera]\naddress = "10.0.0.2"', "camera.address"),
    ],
)
def test_bad_rig_files_name_the_field(tmp_path, old, new, message):
    """Strict types too: a number in quotes or a boolean where a number belongs is refused, not converted."""
    text = SIM_RIG.read_text()
    assert old in text
    bad = tmp_path / "rig.toml"
    bad.write_text(text.replace(old, new))
    with pytest.raises(InputError, match=message.replace(".", r"\.")) as err:
        load_rig(bad)
    assert str(bad) in str(err.value)


def test_pose_ids_that_would_write_outside_the_session_or_repeat_are_refused(tmp_path, builtin_plan):
    """A pose id names its frames' files: `../../etc/evil` would have put them outside the session; two
    poses with one id would both be journaled under it and fit would use one. Each refused naming the
    pose; and the session's frame writer refuses any name that is not a plain file name."""
    import json

    import numpy as np

    from hlr_lab.errors import InputError
    from hlr_lab.formats.plan import read_plan
    from hlr_lab.session.frames import store_frame

    plan = json.loads(builtin_plan.read_text())
    for change, expected in (
        (
            lambda p: p["poses"][0].update(id="../../etc/evil"),
            r"poses\[0\]\.id '\.\./\.\./etc/evil': a pose id is",
        ),
        (
            lambda p: p["poses"][1].update(id=p["poses"][0]["id"]),
            r"poses\[1\]\.id 'p000' is also poses\[0\]'s",
        ),
        (lambda p: p["poses"][0].update(id="lamp-reference"), "reserved"),
        (lambda p: p["poses"][0].update(id=""), "a pose id is"),
    ):
        bad = json.loads(json.dumps(plan))
        change(bad)
        path = tmp_path / "plan.json"
        path.write_text(json.dumps(bad))
        with pytest.raises(InputError, match=expected):
            read_plan(path)
    for name in ("../evil", "a/b", ".hidden", "x/../../y", ""):
        with pytest.raises(ValueError, match="not a frame name"):
            store_frame(tmp_path, name, np.zeros((2, 2, 3), np.uint16), {})
    assert not list(tmp_path.rglob("*.png"))


def test_nan_and_infinity_in_a_file_are_refused_naming_the_field(tmp_path, builtin_plan):
    """JSON's NaN and TOML's nan/inf parse as numbers; every format refuses them where they sit."""
    import json

    from hlr_lab.errors import InputError
    from hlr_lab.formats.plan import read_plan
    from hlr_lab.rig.file import load_rig

    plan = json.loads(builtin_plan.read_text())
    plan["poses"][0]["exposures_s"][0] = float("nan")
    (tmp_path / "plan.json").write_text(json.dumps(plan))
    with pytest.raises(InputError, match=r"poses\[0\]\.exposures_s\[0\]: Input should be a finite number"):
        read_plan(tmp_path / "plan.json")
    text = (Path(__file__).resolve().parents[1] / "hlr_lab" / "data" / "sim-rig.toml").read_text()
    for old, new, field in (("sensitivity = 4095.0", "sensitivity = nan", "sensor.sensitivity"),
                            ("power = 1.0 ", "power = inf ", "light.power")):  # fmt: skip
        assert old in text
        (tmp_path / "rig.toml").write_text(text.replace(old, new))
        with pytest.raises(InputError, match=rf"{field}: Input should be a finite number"):
            load_rig(tmp_path / "rig.toml")


def test_materials_that_are_not_reflectances_are_refused(tmp_path):
    """rd = 2 (twice the light it gets), n ≤ 0, no region at all: refused naming the field."""
    from hlr_lab.errors import InputError
    from hlr_lab.formats.materials import read_materials

    entry = {"id": 0, "color": [200, 100, 50], "vertices": 10, "rd": [0.5, 0.4, 0.3], "rd_se": [0.01] * 3,
             "specular": "unmeasured", "reason": "test", "theta_c_deg": 20.0,
             "pixels": {"diffuse": 100, "highlight": 0}, "residual_rms": 0.01, "estimator": "robust"}  # fmt: skip
    base = {"format": "hlr-lab.materials", "version": 1, "model": "blinn-phong", "regions": [entry]}
    path = tmp_path / "materials.json"
    path.write_text(json.dumps(base))
    assert read_materials(path).regions[0].rd == [0.5, 0.4, 0.3]
    for change, field in (
        ({"regions": [{**entry, "rd": [2.0, 0.4, 0.3]}]}, r"regions\[0\]\.rd\[0\]"),
        (
            {
                "regions": [
                    {
                        **entry,
                        "specular": "measured",
                        "rs": [0.1] * 3,
                        "rs_se": [0.01] * 3,
                        "n": -3.0,
                        "n_se": 1.0,
                        "reason": None,
                    }
                ]
            },
            r"regions\[0\]\.n",
        ),
        ({"regions": []}, "regions"),
    ):
        path.write_text(json.dumps({**base, **change}))
        with pytest.raises(InputError, match=field):
            read_materials(path)


def test_the_aruco_dictionaries_a_rig_file_may_name_are_opencvs():
    """The rig file names a board's dictionary without loading OpenCV: its table must match OpenCV's own."""
    cv2 = pytest.importorskip("cv2")
    for name, markers in ARUCO_DICTIONARIES.items():
        assert cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)).bytesList.shape[0] == markers, name


def test_a_plan_with_a_number_in_quotes_is_refused(tmp_path, builtin_plan):
    """JSON written by hand: "10" where a number belongs is not quietly taken for 10."""
    data = json.loads(builtin_plan.read_text())
    data["poses"][0]["turntable_deg"] = "10"
    bad = tmp_path / "plan.json"
    bad.write_text(json.dumps(data))
    with pytest.raises(InputError, match=r"poses\[0\]\.turntable_deg: Input should be a valid number"):
        read_plan(bad)


def test_the_builtin_true_rigs_are_rig_files_hlr_lab_would_accept(tmp_path):
    """A true rig is a rig file: the world it describes must be one hlr-lab could be told to believe."""
    from sim.true_rig import builtin_true_rigs, true_rig_text

    for name in builtin_true_rigs():
        path = tmp_path / f"{name.removeprefix('builtin:')}.toml"
        path.write_text(true_rig_text(name))
        assert load_rig(path).gantry.arm_radius > 0
