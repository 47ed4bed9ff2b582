"""materials.json and the exports, each re-loaded by an independent reader."""

import json
import struct

import numpy as np
import pytest
import trimesh

from hlr_lab.cli.main import main
from hlr_lab.errors import InputError
from hlr_lab.export.conversion import beckmann_alpha, dielectric_f0, gltf_roughness, ior_for_f0, specular_f0
from hlr_lab.export.gltf import write_gltf
from hlr_lab.export.mitsuba import write_mitsuba
from hlr_lab.export.obj import write_obj
from hlr_lab.export.regions import region_parts
from hlr_lab.fitting import fit_region
from hlr_lab.fitting.synthetic import Truth, synthetic_region
from hlr_lab.formats.materials import (
    PixelCounts,
    materials_file,
    measured_entry,
    read_materials,
    unmeasured_entry,
    write_materials,
)
from hlr_lab.formats.regions import RegionEntry
from hlr_lab.object.procedural import pebble
from hlr_lab.object.segment import segment

TRUTHS = [
    Truth(np.array([0.7, 0.2, 0.15]), np.array([0.3, 0.3, 0.3]), 40.0),
    Truth(np.array([0.2, 0.6, 0.25]), np.array([0.2, 0.25, 0.2]), 120.0),
    Truth(np.array([0.15, 0.25, 0.7]), np.array([0.4, 0.4, 0.45]), 15.0),
]


@pytest.fixture(scope="module")
def pebble_materials(tmp_path_factory):
    obj = pebble()  # the mesh behind builtin:pebble
    seg = segment(obj.mesh)
    entries = []
    regions = [RegionEntry.of(r) for r in seg.regions]
    for region, truth in zip(regions, TRUTHS, strict=False):
        r = synthetic_region(
            truth, shape="sphere", pixels=8000, bits=12, read_noise_dn=2, full_scale=1.5, seed=region.id
        )
        entries.append(measured_entry(region, fit_region(r.intensity, r.irradiance, r.cos_alpha, r.cos_beta)))
    last = regions[-1]  # its highlight was never photographed
    entries.append(
        unmeasured_entry(
            last,
            [0.5, 0.5, 0.4],
            [0.001] * 3,
            reason="only 3 highlight pixels",
            theta_c_deg=20.0,
            pixels=PixelCounts(diffuse=900, highlight=3),
            residual_rms=0.002,
            estimator="robust",
        )
    )
    path = tmp_path_factory.mktemp("m") / "materials.json"
    write_materials(path, materials_file(entries, mesh="builtin:pebble", sha256=obj.mesh.sha256))
    return path, obj.mesh, seg


def test_materials_round_trip(pebble_materials):
    path, _, seg = pebble_materials
    m = read_materials(path)
    assert m.model == "blinn-phong"
    assert len(m.regions) == seg.n_regions
    for entry, truth in zip(m.regions, TRUTHS, strict=False):
        assert np.allclose(entry.rd, truth.rd, rtol=0.01)
        assert entry.n == pytest.approx(truth.n, rel=0.05)
        assert entry.specular == "measured"
        assert entry.pixels.highlight > 0
    last = m.regions[-1]
    assert last.specular == "unmeasured"
    assert last.rs is None
    assert last.n is None
    assert "3 highlight" in last.reason


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d["regions"][0].pop("n"), "measured specular needs"),
        (lambda d: d["regions"][-1].update(rs=[0.1, 0.1, 0.1]), "unmeasured specular"),
        (lambda d: d.update(model="cook-torrance"), "blinn-phong"),
        (lambda d: d["regions"][0].update(rd=[0.5, -0.1, 0.2]), "greater than or equal to 0"),
        (lambda d: d["regions"].append(dict(d["regions"][0])), "appears twice"),
    ],
)
def test_malformed_materials_are_refused(pebble_materials, tmp_path, change, message):
    data = json.loads(pebble_materials[0].read_text())
    change(data)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))
    with pytest.raises(InputError, match=message):
        read_materials(bad)


@pytest.fixture(scope="module")
def parts(pebble_materials):
    path, mesh, seg = pebble_materials
    return region_parts(mesh, seg, read_materials(path), source=str(path))


def test_obj_and_mtl_reload_with_trimesh(parts, tmp_path, pebble_materials):
    obj, mtl = write_obj(tmp_path / "pebble.obj", parts)
    assert "Blinn-Phong exponent" in mtl.read_text()
    scene = trimesh.load(obj, group_material=True)
    geoms = list(scene.geometry.values())
    assert len(geoms) == len(parts)
    assert sum(len(g.faces) for g in geoms) == len(pebble_materials[1].faces)
    by_kd = {tuple(np.round(p.rd * 255).astype(int)): p for p in parts}
    for g in geoms:
        material = g.visual.material
        part = by_kd[tuple(int(x) for x in material.diffuse[:3])]  # trimesh keeps Kd as 8-bit
        np.testing.assert_allclose(np.asarray(material.specular[:3]) / 255, part.rs, atol=1 / 255)
        assert material.glossiness == pytest.approx(part.n, abs=1e-3)


def test_gltf_reloads_with_trimesh_and_carries_the_fit(parts, tmp_path):
    (glb,) = write_gltf(tmp_path / "pebble.glb", parts)
    scene = trimesh.load(glb)
    geoms = list(scene.geometry.values())
    assert len(geoms) == len(parts)
    assert sorted(len(g.vertices) for g in geoms) == sorted(len(p.vertices) for p in parts)
    for g in geoms:
        m = g.visual.material
        part = next(
            p for p in parts if np.allclose(np.asarray(m.baseColorFactor[:3]) / 255, p.rd, atol=1 / 255)
        )
        assert m.roughnessFactor == pytest.approx(gltf_roughness(part.n), rel=1e-6)
        assert m.metallicFactor == 0
    raw = glb.read_bytes()
    (json_len,) = struct.unpack_from("<I", raw, 12)
    doc = json.loads(raw[20 : 20 + json_len])
    spec = doc["materials"][0]["extensions"]["KHR_materials_specular"]["specularColorFactor"]
    np.testing.assert_allclose(spec, specular_f0(parts[0].rs, parts[0].n) / 0.04)
    assert doc["materials"][-1]["extras"]["hlr_lab"]["specular"] == "unmeasured"


def test_mitsuba_scene_loads(parts, tmp_path):
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")  # the loader needs no JIT backend
    files = write_mitsuba(tmp_path / "scene", parts)
    scene = mi.load_file(str(files[0]))
    assert len(scene.shapes()) == len(parts)
    params = mi.traverse(scene)
    alpha = [params[f"{p.name}.alpha"] for p in parts]
    assert [float(a) for a in alpha] == pytest.approx([beckmann_alpha(p.n) for p in parts], rel=1e-5)


def test_conversions():
    assert dielectric_f0(ior_for_f0(0.013)) == pytest.approx(0.013)
    assert dielectric_f0(1.5) == pytest.approx(0.04)
    assert beckmann_alpha(2 / 0.3**2 - 2) == pytest.approx(0.3)
    assert gltf_roughness(2 / 0.09**2 - 2) == pytest.approx(0.3)
    # a measured peak Rs equals F0 (n+8)/8
    assert specular_f0(np.array([0.5]), 92.0)[0] * (92 + 8) / 8 == pytest.approx(0.5)


def test_export_command(capsys, pebble_materials, tmp_path):
    path = pebble_materials[0]
    for fmt, out in (("obj", "p.obj"), ("gltf", "p.glb"), ("mitsuba", "scene")):
        code = main(
            ["export", str(path), "--mesh", "builtin:pebble", "--format", fmt, "-o", str(tmp_path / out)]
        )
        assert code == 0, capsys.readouterr().err
    assert (tmp_path / "p.mtl").exists()
    assert (tmp_path / "scene" / "scene.xml").exists()
    code = main(
        ["export", str(path), "--mesh", "builtin:pebble", "--format", "gltf", "-o", str(tmp_path / "x.obj")]
    )
    assert code == 1
    assert "--output: --format gltf writes a .glb file: give a name ending in .glb" in capsys.readouterr().err
    assert not (tmp_path / "x.obj").exists()


def test_export_refuses_regions_that_do_not_match(capsys, pebble_materials, tmp_path):
    data = json.loads(pebble_materials[0].read_text())
    data["regions"][0]["color"] = [0, 0, 255]
    data.pop("sha256")
    bad = tmp_path / "m.json"
    bad.write_text(json.dumps(data))
    code = main(
        ["export", str(bad), "--mesh", "builtin:pebble", "--format", "obj", "-o", str(tmp_path / "p.obj")]
    )
    assert code == 1
    assert "--regions" in capsys.readouterr().err
    assert not (tmp_path / "p.obj").exists()


def test_a_region_without_a_material_is_exported_with_a_named_stand_in(capsys, pebble_materials, tmp_path):
    """A materials file that lacks a region (too few pixels, never seen): every face is still exported —
    the missing region as its own colour, diffuse only, under a name that says so in each format — and
    the command warns."""
    from hlr_lab.formats.materials import read_materials

    path, mesh, _ = pebble_materials
    partial = read_materials(path)
    partial = partial.model_copy(update={"regions": partial.regions[1:]})  # region 0 has no material
    write_materials(tmp_path / "partial.json", partial)
    for fmt, out in (("obj", "p.obj"), ("gltf", "p.glb"), ("mitsuba", "scene")):
        command = ["export", str(tmp_path / "partial.json"), "--mesh", "builtin:pebble", "--format", fmt, "-o",
                   str(tmp_path / out)]  # fmt: skip
        assert main(command) == 0
        assert "region(s) 0 had no fitted material" in capsys.readouterr().err
    loaded = trimesh.load(tmp_path / "p.obj", force="mesh", process=False)
    assert len(loaded.faces) == len(mesh.faces)  # no hole
    assert "newmtl region_0_stand_in_not_measured" in (tmp_path / "p.mtl").read_text()
    assert "STAND-IN" in (tmp_path / "p.mtl").read_text()
    scene = trimesh.load(tmp_path / "p.glb", process=False)
    assert sum(len(g.faces) for g in scene.geometry.values()) == len(mesh.faces)
    assert "region_0_stand_in_not_measured" in (tmp_path / "scene" / "scene.xml").read_text()
