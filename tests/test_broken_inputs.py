"""The broken inputs a careless or hostile hand gives hlr-lab, at the command line, in one table: each is
refused with one `error:` line (exit 1, or 2 for a usage error) that names the file, field or option,
with no traceback and no "internal error", and nothing is written where the command would write.

Other tables cover parts of this in depth: numbers at the options (tests/test_cli.py), read-only and
full disks (tests/test_disk_full.py), damaged sessions (tests/test_journal_damage.py), and every file
reader against generated broken files (tests/test_readers_property.py)."""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
import pytest

from hlr_lab.cli.main import main


@dataclass(frozen=True)
class Case:
    """``make(folder, plan, session)`` writes the broken input into ``folder`` and returns the command;
    ``plan`` is a good plan, ``session`` a copy of a finished session to damage. The error line must
    match ``said``; ``written``: what must not exist afterwards (relative to ``folder``)."""

    name: str
    make: Callable[[Path, Path, Path], list[str]]
    said: str
    status: int = 1
    written: str = "out"


def _edit_json(source: Path, target: Path, change: Callable[[dict], None]) -> Path:
    data = json.loads(source.read_text())
    change(data)
    target.write_text(json.dumps(data))
    return target


def _plan_with(change: Callable[[dict], None]):
    def make(folder: Path, plan: Path, session: Path) -> list[str]:
        broken = _edit_json(plan, folder / "plan.json", change)
        return ["acquire", "--plan", str(broken), "--sim", "--dry-run", "--out", str(folder / "out")]

    return make


def _rig_with(pattern: str, replacement: str):
    def make(folder: Path, plan: Path, session: Path) -> list[str]:
        text = (resources.files("hlr_lab.data") / "sim-rig.toml").read_text()
        rig = folder / "rig.toml"
        rig.write_text(re.sub(pattern, replacement, text, count=1, flags=re.M))
        return ["plan", "--mesh", "builtin:pebble", "--rig", str(rig), "-o", str(folder / "out")]

    return make


def _true_rig_with(pattern: str, replacement: str):
    """The simulated world built from a rig file with a mistake: hlr-lab's own checks name it."""

    def make(folder: Path, plan: Path, session: Path) -> list[str]:
        text = (resources.files("hlr_lab.data") / "sim-rig.toml").read_text()
        true_rig = folder / "true.toml"
        true_rig.write_text(re.sub(pattern, replacement, text, count=1, flags=re.M))
        return [
            "acquire",
            "--plan",
            str(plan),
            "--sim",
            "--true-rig",
            str(true_rig),
            "--out",
            str(folder / "out"),
        ]

    return make


def _materials_with(change: Callable[[dict], None]):
    def make(folder: Path, plan: Path, session: Path) -> list[str]:
        good = {"format": "hlr-lab.materials", "version": 1, "model": "blinn-phong",
                "regions": [{"id": 0, "color": [200, 50, 40], "vertices": 10, "rd": [0.5, 0.1, 0.1],
                             "rd_se": [0.001] * 3, "specular": "unmeasured", "reason": "r", "theta_c_deg": 5.0,
                             "pixels": {"diffuse": 100, "highlight": 0}, "residual_rms": 0.01,
                             "estimator": "robust"}]}  # fmt: skip
        change(good)
        (folder / "m.json").write_text(json.dumps(good))
        return ["export", str(folder / "m.json"), "--mesh", "builtin:pebble", "--format", "obj", "-o",
                str(folder / "out" / "m.obj")]  # fmt: skip

    return make


def _mesh(text: bytes, suffix: str = ".obj"):
    def make(folder: Path, plan: Path, session: Path) -> list[str]:
        (folder / f"m{suffix}").write_bytes(text)
        return ["segment", "--mesh", str(folder / f"m{suffix}"), "-o", str(folder / "out")]

    return make


def _session_with(damage: Callable[[Path], None]):
    def make(folder: Path, plan: Path, session: Path) -> list[str]:
        damage(session)
        return ["fit", str(session), "-o", str(folder / "out")]

    return make


def _replace_frame(session: Path, pixels_of: Callable[[np.ndarray], np.ndarray], every: bool = False) -> None:
    """The first frame's image (``every``: every frame's) replaced, its checksum updated in the journal and
    the sidecar (as a careful hand would), so only its contents give it away."""

    def encoded(image: Path) -> bytes:
        return cv2.imencode(".png", pixels_of(cv2.imread(str(image), cv2.IMREAD_UNCHANGED)))[1].tobytes()

    _replace_image_bytes(session, encoded, every)


def _replace_image_bytes(session: Path, data_of: Callable[[Path], bytes], every: bool = False) -> None:
    journal = session / "journal.jsonl"
    events = [json.loads(line) for line in journal.read_text().splitlines()]
    for e in [e for e in events if e["event"] == "frame"][: None if every else 1]:
        image = session / e["file"]
        data = data_of(image)
        image.write_bytes(data)
        sidecar_path = session / e["sidecar"]
        sidecar = json.loads(sidecar_path.read_text())
        sidecar["image_sha256"] = e["sha256"] = hashlib.sha256(data).hexdigest()
        sidecar_path.write_text(json.dumps(sidecar))
        e["sidecar_sha256"] = hashlib.sha256(sidecar_path.read_bytes()).hexdigest()
    journal.write_text("".join(json.dumps(x) + "\n" for x in events))


def _in_step_with_exposure(level_per_s: float) -> Callable[[Path], bytes]:
    """A frame of one uniform value, in proportion to its sidecar's exposure: a bracket that agrees with
    itself, in which nothing follows the light."""

    def data_of(image: Path) -> bytes:
        exposure = json.loads(image.with_suffix(".json").read_text())["exposure_s"]
        shape = cv2.imread(str(image), cv2.IMREAD_UNCHANGED).shape
        return cv2.imencode(".png", np.full(shape, round(level_per_s * exposure), np.uint16))[1].tobytes()

    return data_of


def _swap_exposures(session: Path) -> None:
    """Every pose's first two exposures swapped in the sidecars and the journal, checksums kept consistent:
    only the pixels can tell."""
    journal = session / "journal.jsonl"
    events = [json.loads(line) for line in journal.read_text().splitlines()]
    frames = [e for e in events if e["event"] == "frame" and not e["dark"] and e["exposure_index"] in (0, 1)]
    for pose in {e["pose"] for e in frames}:
        a, b = (next(e for e in frames if e["pose"] == pose and e["exposure_index"] == k) for k in (0, 1))
        a["exposure_s"], b["exposure_s"] = b["exposure_s"], a["exposure_s"]
        for e in (a, b):
            path = session / e["sidecar"]
            sidecar = json.loads(path.read_text())
            sidecar["exposure_s"] = sidecar["camera"]["exposure_s"] = e["exposure_s"]
            path.write_text(json.dumps(sidecar))
            e["sidecar_sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    journal.write_text("".join(json.dumps(x) + "\n" for x in events))


def _png_header_only(width: int, height: int) -> bytes:
    """A PNG that claims width × height pixels (RGB, 16-bit) and holds none: what a decoder would try to
    allocate is what the header says."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 16, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b"")


def _plan_text(change: Callable[[str], str]):
    def make(folder: Path, plan: Path, session: Path) -> list[str]:
        (folder / "plan.json").write_text(change(plan.read_text()))
        return [
            "acquire",
            "--plan",
            str(folder / "plan.json"),
            "--sim",
            "--dry-run",
            "--out",
            str(folder / "out"),
        ]

    return make


def _plan_mesh(make_mesh: Callable[[Path], str]):
    """A dry run of a plan whose object.mesh is what ``make_mesh(folder)`` makes and names."""

    def make(folder: Path, plan: Path, session: Path) -> list[str]:
        return _plan_with(_set("object.mesh", make_mesh(folder)))(folder, plan, session)

    return make


def _fifo(folder: Path) -> str:
    os.mkfifo(folder / "m.ply")
    return "m.ply"


def _sidecar(session: Path, change: Callable[[dict], None]) -> None:
    journal = session / "journal.jsonl"
    events = [json.loads(line) for line in journal.read_text().splitlines()]
    e = next(e for e in events if e["event"] == "frame")
    path = session / e["sidecar"]
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))
    e["sidecar_sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    journal.write_text("".join(json.dumps(x) + "\n" for x in events))


def _report_with_foreign_materials(folder: Path, plan: Path, session: Path) -> list[str]:
    assert main(["fit", str(session)]) == 0
    _edit_json(session / "materials.json", session / "materials.json", _set("sha256", "0" * 64))
    return ["report", str(session), "-o", str(folder / "out")]


def _set(path: str, value):
    """A change that sets ``path`` (dotted, with list indices) in a JSON document."""

    def change(doc: dict) -> None:
        *parents, last = [int(p) if p.isdigit() else p for p in path.split(".")]
        for p in parents:
            doc = doc[p]
        doc[last] = value

    return change


def _two_poses_named_alike(doc: dict) -> None:
    doc["poses"][1]["id"] = doc["poses"][0]["id"]


def _resumed_on_another_rig(folder: Path, plan: Path, session: Path) -> list[str]:
    """The session was acquired on the simulated rig; resumed with a rig file whose devices do not
    exist: the changed rig is said before any device is opened (else: a device that does not answer)."""
    text = (resources.files("hlr_lab.data") / "sim-rig.toml").read_text()
    rig = folder / "rig.toml"
    for section, link in (
        ("gantry", 'port = "/dev/does-not-exist"'),
        ("turntable", 'address = "127.0.0.1:9"'),
    ):
        text = text.replace(f"[{section}]\n", f"[{section}]\n{link}\n", 1)
    rig.write_text(text)
    shutil.copy(plan, folder / "plan.json")
    return ["acquire", "--plan", str(folder / "plan.json"), "--rig", str(rig), "--out", str(session)]


CASES = [
    Case("pose id that climbs out of the session", _plan_with(_set("poses.0.id", "../../etc/evil")), r"poses\[0\]\.id"),
    Case("two poses with one id", _plan_with(_two_poses_named_alike), r"poses\[1\]\.id"),
    Case("a light position of 1e300 m", _plan_with(_set("poses.0.light.position_m", [1e300, 0, 0])),
         r"poses\[0\]\.light\.position_m\[0\]"),
    Case("a NaN exposure", _plan_with(_set("poses.0.exposures_s", [float("nan")])),
         r"poses\[0\]\.exposures_s\[0\]: Input should be a finite number"),
    Case("a plan with no poses", _plan_with(_set("poses", [])), r"plan\.json: poses: the plan has no poses"),
    Case("a plan nested 100 000 deep", lambda f, p, s: (f / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
         and ["acquire", "--plan", str(f / "deep.json"), "--sim", "--out", str(f / "out")],
         r"deep\.json: not valid JSON \(nested too deeply"),
    Case("an exposure of a million seconds", _plan_with(_set("poses.0.exposures_s", [1e6])), r"exposures_s\[0\]"),
    Case("the paper's sphere, for no rig", _plan_with(_set("parameters.sphere_source", "scale")),
         r"parameters\.sphere_source: this is an analysis plan"),
    Case("a plan that is a folder", lambda f, p, s: (f / "d.json").mkdir() or
         ["acquire", "--plan", str(f / "d.json"), "--sim", "--out", str(f / "out")], "d.json", status=2),
    Case("a truncated plan", lambda f, p, s: (f / "t.json").write_bytes(p.read_bytes()[:200]) and
         ["acquire", "--plan", str(f / "t.json"), "--sim", "--out", str(f / "out")], r"t\.json"),
    Case("a camera 1e8 pixels wide", _rig_with(r"^width = .*$", "width = 100000000"), r"camera\.width"),
    Case("a NaN focal length", _rig_with(r"^matrix = \[\[[0-9.]+", "matrix = [[nan"), r"camera\.matrix"),
    Case("an ArUco dictionary OpenCV does not have", _rig_with(r"^dictionary = .*$", 'dictionary = "DICT_9X9_50"'),
         r"calibration\.board: dictionary 'DICT_9X9_50'"),
    Case("a camera at the gantry centre", _rig_with(r"^position_m = .*$", "position_m = [0.0, 0.0, 0.08]"),
         r"camera"),
    Case("a true rig with a misspelt field", _true_rig_with(r"^profile_acceleration = ", "profile_acceleraton = "),
         r"true\.toml: gantry\.profile_acceleraton: Extra inputs are not permitted"),
    Case("materials with no region", _materials_with(_set("regions", [])), r"regions"),
    Case("an Rd of 2", _materials_with(_set("regions.0.rd", [2.0, 0.1, 0.1])), r"regions\[0\]\.rd\[0\]"),
    Case("a negative exponent", _materials_with(lambda d: d["regions"][0].update(specular="measured", n=-3.0,
         rs=[0.1] * 3, rs_se=[0.01] * 3, n_se=1.0)), r"regions\[0\]\.n"),
    Case("a mesh of random bytes", _mesh(bytes(range(256)) * 4),
         r"m\.obj: not a text OBJ file \(byte 0x80 at offset 128"),
    Case("a face naming a vertex the mesh lacks", _mesh(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"),
         r"m\.obj: a face refers to a vertex the file does not have"),
    Case("a PLY face naming a vertex the mesh lacks", _mesh(
         b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
         b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n",
         ".ply"), r"m\.ply: face 0 refers to vertex 7, but the file has 3"),
    Case("a mesh without faces", _mesh(b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"), r"m\.obj: the mesh has no faces"),
    Case("an output that is a folder", lambda f, p, s: (f / "out").mkdir() or
         ["segment", "--mesh", "builtin:pebble", "-o", str(f / "out")], r"out.* is a directory", status=2,
         written=""),
    Case("a NaN in session.json", _session_with(lambda s: (s / "session.json").write_text(
         (s / "session.json").read_text().replace('"started_at": ', '"started_at": NaN, "x": ', 1))),
         r"session\.json: started_at: is not a number"),
    Case("a journal that is a folder", _session_with(lambda s: (s / "journal.jsonl").unlink() or
         (s / "journal.jsonl").mkdir()), r"journal\.jsonl"),
    Case("an 8-bit frame in a 16-bit session", _session_with(lambda s: _replace_frame(
         s, lambda px: (px >> 8).astype(np.uint8))), r"frames/p000_e0\.png.*8-bit"),
    Case("a frame of another size", _session_with(lambda s: _replace_frame(s, lambda px: px[:-2])),
         r"frames/p000_e0\.png"),
    Case("a sidecar's ticks of 1e300", _session_with(lambda s: _sidecar(
         s, _set("measured.gantry_ticks", [1e300, 0]))), r"gantry_ticks"),
    Case("a sidecar's negative exposure", _session_with(lambda s: _sidecar(s, lambda d: d.update(
         exposure_s=-1.0))), r"exposure"),
    Case("resumed on another rig", _resumed_on_another_rig, r"started with another rig", written=""),
    # issue 20, §3–4: values that lie and inputs that crashed or hung
    Case("a plan integer of 5000 digits",
         _plan_text(lambda t: t.replace('"version": 1', '"version": ' + "1" * 5000, 1)),
         r"plan\.json: not valid JSON for hlr-lab \(Exceeds the limit \(4300 digits\)"),
    Case("a rig integer of 5000 digits", _rig_with(r"^width = .*$", "width = " + "1" * 5000),
         r"rig\.toml: not valid TOML for hlr-lab \(Exceeds the limit"),
    Case("a misspelt pose key", _plan_with(lambda d: d["poses"][0].update(exposure_s=[0.01])),
         r"poses\[0\]: unknown key 'exposure_s': did you mean 'exposures_s'\?"),
    Case("a singular placement", _plan_with(_set("object.mesh_to_turntable", [[0.0] * 4] * 3 + [[0, 0, 0, 1.0]])),
         r"object\.mesh_to_turntable: the placement is singular"),
    Case("a mirrored placement", _plan_with(_set("object.mesh_to_turntable",
         [[-1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])),
         r"mesh_to_turntable: the placement mirrors"),
    Case("a dry run of a plan whose mesh is a FIFO", _plan_mesh(_fifo), r"m\.ply: is not a regular file"),
    Case("a dry run of a plan whose mesh is /dev/zero", _plan_mesh(lambda f: "/dev/zero"),
         r"/dev/zero: is not a regular file"),
    Case("a dry run of a plan whose mesh is a folder", _plan_mesh(lambda f: "."), r"in: is not a regular file"),
    Case("a dry run of a plan whose mesh is another file", _plan_mesh(lambda f: "../../../../../../../etc/passwd"),
         r"etc/passwd"),
    Case("a sphere 1e300 times the object", lambda f, p, s: ["plan", "--mesh", "builtin:pebble", "--sim",
         "--sphere-scale", "1e300", "-o", str(f / "out")], r"--sphere-scale must exceed 1 and be at most 100"),
    Case("a view the turntable cannot reach", lambda f, p, s: ["plan", "--mesh", "builtin:pebble", "--sim",
         "--views", "0,200", "-o", str(f / "out")],
         r"--views: 200° is outside the rig's turntable limits \[-180, 180\]"),
    Case("a greyscale frame in an RGB bracket", _session_with(lambda s: _replace_frame(s, lambda px: px[..., 1])),
         r"frames/p000_e0\.png: it has 1 channel, where hlr-lab fits RGB frames"),
    Case("a frame of 60000 × 60000 pixels", _session_with(lambda s: _replace_image_bytes(
         s, lambda _: _png_header_only(60000, 60000))), r"frames/p000_e0\.png: it is 60000×60000 pixels"),
    Case("a sidecar's steps of 1e15", _session_with(lambda s: _sidecar(s, _set("measured.turntable_steps", 10**15))),
         r"turntable_steps"),
    Case("a sidecar's ticks of 1e30", _session_with(lambda s: _sidecar(s, _set("measured.gantry_ticks", [10**30, 0]))),
         r"gantry_ticks"),
    Case("materials of another mesh reported as the session's", _report_with_foreign_materials,
         r"materials\.json: sha256: its materials are of another mesh"),
    Case("every frame saturated: no region to fit", _session_with(lambda s: _replace_frame(
         s, lambda px: np.full_like(px, 4095), every=True)), r"session: no region could be fitted \(region 0: "),
    Case("every frame black: the lamp lit nothing", _session_with(lambda s: _replace_frame(
         s, np.zeros_like, every=True)), r"session: every pixel of the object is black in every frame of its 2 pose"),
    Case("two exposures swapped, checksums consistent", _session_with(_swap_exposures),
         r"frames/p000_e[01]\.png \(0\.0\d+ s\) is [0-9.]+× as bright per second of exposure as frames/p000_e"),
    Case("frames uniform, in step with their exposures", _session_with(lambda s: _replace_image_bytes(
         s, _in_step_with_exposure(51200.0), every=True)),
         r"no region could be fitted \(region 0: its \d+ pixels do not brighten where the lamp's light falls"),
    Case("a frame cut short, checksums consistent", _session_with(lambda s: _replace_image_bytes(
         s, lambda image: image.read_bytes()[: image.stat().st_size // 2])),
         r"frames/p000_e0\.png is not a whole PNG image although its checksum matches \(its IDAT chunk is cut"),
    Case("a frame with a flipped bit, checksums consistent", _session_with(lambda s: _replace_image_bytes(
         s, lambda image: (lambda d: d[:4000] + bytes([d[4000] ^ 1]) + d[4001:])(image.read_bytes()))),
         r"frames/p000_e0\.png is not a whole PNG image .*\(its IDAT chunk fails its CRC\)"),
    Case("a region taken out of the plan", _plan_with(lambda d: d["object"]["regions"].pop()),
         r"plan\.json: object\.regions: its regions hold \d+ faces, the mesh has 20480: a region was taken out"),
]  # fmt: skip


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_a_broken_input_is_one_line_naming_it(case, tmp_path, builtin_plan, finished_session, capsys):
    session = tmp_path / "session"
    shutil.copytree(finished_session, session)
    folder = tmp_path / "in"
    folder.mkdir()
    command = case.make(folder, builtin_plan, session)
    capsys.readouterr()
    assert main(command) == case.status
    said = capsys.readouterr().err
    errors = [line for line in said.splitlines() if "error" in line.lower()]
    assert len(errors) == 1, said  # (acquire prints its motion table before anything can go wrong)
    assert said.strip().splitlines()[-1] == errors[0], said
    assert errors[0].startswith("error: "), errors[0]
    assert "Traceback" not in said
    assert re.search(case.said, errors[0]), errors[0]
    if case.written:
        assert not (folder / case.written).exists()


def test_a_frame_of_a_pose_the_plan_lacks_is_left_out_naming_it(tmp_path, finished_session, capsys):
    """A complete frame (image, sidecar, checksums, journal line) for a pose the plan does not have: its
    geometry would be no one's; fit leaves it out and says so."""
    session = tmp_path / "session"
    shutil.copytree(finished_session, session)
    journal = session / "journal.jsonl"
    first = next(e for e in map(json.loads, journal.read_text().splitlines()) if e["event"] == "frame")
    sidecar = json.loads((session / first["sidecar"]).read_text())
    sidecar["pose"] = "zz9"
    (session / "frames" / "zz9_e0.png").write_bytes((session / first["file"]).read_bytes())
    (session / "frames" / "zz9_e0.json").write_text(json.dumps(sidecar))
    written = hashlib.sha256((session / "frames" / "zz9_e0.json").read_bytes()).hexdigest()
    line = {**first, "pose": "zz9", "file": "frames/zz9_e0.png", "sidecar": "frames/zz9_e0.json",
            "sidecar_sha256": written}  # fmt: skip
    with journal.open("a") as f:
        f.write(json.dumps(line) + "\n")
    assert main(["fit", str(session), "-o", str(tmp_path / "m.json")]) == 0
    assert "frames/zz9_e0.png: its pose 'zz9' is not in the session's plan" in " ".join(
        capsys.readouterr().err.split()
    )


def test_a_damaged_frame_is_one_line_with_nothing_from_libpng(tmp_path, finished_session, capfd):
    """libpng prints its own "libpng error: …" line straight to the console (file descriptor 2, which only
    capfd sees) before OpenCV gives up: the frame is checked before it is decoded."""
    session = tmp_path / "session"
    shutil.copytree(finished_session, session)
    _replace_image_bytes(session, lambda image: image.read_bytes()[:-5000])
    capfd.readouterr()
    assert main(["fit", str(session), "-o", str(tmp_path / "m.json")]) == 1
    err = capfd.readouterr().err
    assert "libpng" not in err, err
    assert re.search(r"^error: .*frames/p000_e0\.png is not a whole PNG image", err, re.M), err


def test_a_texture_repainted_after_planning_is_refused(tmp_path, builtin_plan):
    """The plan records its texture's pixels (object.texture_sha256) however the image was found (here an
    OBJ's .mtl): repainted after planning, its regions are no longer the plan's."""
    from hlr_lab.errors import InputError
    from hlr_lab.formats.plan import read_plan
    from hlr_lab.formats.planned_object import load_planned_mesh
    from hlr_lab.object.mesh import file_sha256, load_mesh, texture_sha256

    cv2.imwrite(str(tmp_path / "paint.png"), np.full((8, 8, 3), (40, 90, 200), np.uint8))
    (tmp_path / "quad.mtl").write_text("newmtl paint\nKd 1 1 1\nmap_Kd paint.png\n")
    obj = tmp_path / "quad.obj"
    obj.write_text(
        "mtllib quad.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "usemtl paint\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
    )
    doc = json.loads(builtin_plan.read_text())
    doc["object"].update(mesh="quad.obj", sha256=file_sha256(obj), texture_sha256=texture_sha256(load_mesh(obj)),
                         regions=[{"id": 0, "color": [200, 90, 40], "vertices": 4, "faces": 2}])  # fmt: skip
    plan_path = tmp_path / "plan.json"
    plan_path.write_text(json.dumps(doc))
    assert len(load_planned_mesh(read_plan(plan_path), plan_path).faces) == 2
    cv2.imwrite(str(tmp_path / "paint.png"), np.full((8, 8, 3), (40, 200, 90), np.uint8))
    with pytest.raises(InputError, match=r"object\.texture_sha256: the texture of quad\.obj has changed"):
        load_planned_mesh(read_plan(plan_path), plan_path)


def test_a_black_level_that_is_not_the_rig_files_is_named_by_the_fit(tmp_path, finished_session, capsys):
    """Frames 64 DN brighter than their sensor's black level in the rig file (bench-night's camera against
    the drawing): the brackets measure the difference (not mistaken for exposures that lie) and the fit
    says so, naming the setting and the procedure that measures it."""
    session = tmp_path / "session"
    shutil.copytree(finished_session, session)
    _replace_frame(session, lambda px: px + np.uint16(64), every=True)
    assert main(["fit", str(session), "-o", str(tmp_path / "m.json")]) == 0
    printed = capsys.readouterr()
    said = " ".join((printed.out + printed.err).split())
    assert re.search(r"warning: the exposure brackets put the sensor's black level \+6[34]\.\d DN from the rig "
                     r"file's \[sensor\] black_level_dn = 0 .*hlr-lab calibrate radiometric", said), said  # fmt: skip
    found = json.loads((tmp_path / "fit-diagnostics.json").read_text())["black_level"]
    assert found["brackets"] == 2, found
    assert abs(found["offset_dn"] - 64) < 1, found
