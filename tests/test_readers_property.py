"""Every reader of a file a user (or a careless or hostile hand) can give hlr-lab, fed generated broken
files: a valid example mutated (a value replaced by another type, NaN, ±inf, a huge or negative number,
a key deleted or duplicated), then possibly truncated or bit-flipped, or plain random bytes. Each must
end in a valid object or the one exception that becomes a clean `error:` line (InputError; SceneError
for the simulator's scene reader, which the command line turns into one); never anything else, and no
warning (the suite turns warnings into errors).

Profiles (tests/conftest.py): "ci" — 150 cases per format, in the test command; "nightly" — 10 000 per
format: ``HLR_LAB_HYPOTHESIS=nightly pytest tests/test_readers_property.py``."""

from __future__ import annotations

import contextlib
import copy
import hashlib
import json
import math
import re
import tempfile
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hlr_lab.campaign.runner import load_campaign
from hlr_lab.errors import InputError
from hlr_lab.formats.materials import read_materials
from hlr_lab.formats.plan import read_plan
from hlr_lab.formats.regions import read_regions, write_regions
from hlr_lab.instrument.motion import motion_targets
from hlr_lab.object.mesh import load_mesh, write_vertex_coloured_ply
from hlr_lab.object.procedural import pebble
from hlr_lab.object.segment import segment
from hlr_lab.reflectance.session_fit import _views
from hlr_lab.rig.file import load_rig
from hlr_lab.session.frames import store_frame
from hlr_lab.session.journal import load_journal
from hlr_lab.session.metadata import SESSION, read_record, session_plan, start_or_resume
from sim.render.scene import SceneError, load_scene

BROKEN = settings(suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large], deadline=None)

ODD_VALUES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -1, 1e300, -1e300, 1e-320, 2**63, 65536, 0.5]),
    st.text(max_size=12),
    st.sampled_from(["../../etc/evil", "", "p000", "builtin:pebble", "x" * 300]),
    st.builds(list),  # new ones each time: a later mutation may go inside
    st.builds(dict),
    st.lists(st.integers(-5, 5000), max_size=4),
)


def _paths(doc, prefix=()) -> list[tuple]:
    """Key paths to every value of a JSON document (only the first three items of a list)."""
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:3]):
            out += _paths(v, (*prefix, i))
    return out


@st.composite
def mutated_json(draw, doc) -> bytes:
    """``doc`` with 1–3 values replaced, deleted or duplicated, serialised (NaN and inf as Python writes
    them), then maybe truncated or bit-flipped; or random bytes."""
    if draw(st.integers(0, 19)) == 0:
        return draw(st.binary(max_size=300))
    doc = copy.deepcopy(doc)
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(doc)
        if not paths:
            break
        *parent_path, key = draw(st.sampled_from(paths))
        parent = doc
        for k in parent_path:
            parent = parent[k]
        action = draw(st.sampled_from(["replace", "replace", "delete", "duplicate"]))
        if action == "replace":
            parent[key] = draw(ODD_VALUES)
        elif action == "delete":
            del parent[key]
        elif isinstance(parent, list):
            parent.insert(key, copy.deepcopy(parent[key]))
    return _damaged(draw, json.dumps(doc).encode())


def _damaged(draw, data: bytes) -> bytes:
    how = draw(st.sampled_from(["whole", "whole", "truncated", "flipped"]))
    if how == "truncated" and data:
        return data[: draw(st.integers(0, len(data) - 1))]
    if how == "flipped" and data:
        data = bytearray(data)
        for _ in range(draw(st.integers(1, 4))):
            data[draw(st.integers(0, len(data) - 1))] ^= 1 << draw(st.integers(0, 7))
        return bytes(data)
    return data


TOML_VALUES = st.sampled_from(
    ["nan", "inf", "-inf", "1e400", "-1", "0", "1e300", '"text"', "[]", "{}", "true", "[1, 2]", '"../../x"',
     "99999999999999999999", "-0.0", '[nan, 0, 1]', '"builtin:nope"', "{ a = 1 }"]
)  # fmt: skip


@st.composite
def mutated_toml(draw, text: str) -> bytes:
    """``text`` (TOML) with 1–3 `key = value` lines given another value, deleted or duplicated, then maybe
    truncated or bit-flipped; or random bytes."""
    if draw(st.integers(0, 19)) == 0:
        return draw(st.binary(max_size=300))
    lines = text.splitlines()
    for _ in range(draw(st.integers(1, 3))):
        assignments = [i for i, line in enumerate(lines) if re.match(r"^\s*[\w.\"-]+\s*=", line)]
        if not assignments:
            break
        i = draw(st.sampled_from(assignments))
        action = draw(st.sampled_from(["replace", "replace", "delete", "duplicate"]))
        if action == "replace":
            lines[i] = lines[i].split("=", 1)[0] + "= " + draw(TOML_VALUES)
        elif action == "delete":
            del lines[i]
        else:
            lines.insert(i, lines[i])
    return _damaged(draw, "\n".join(lines).encode())


# --- valid examples, made once -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def examples(tmp_path_factory, plan_file, rig) -> dict:
    root = tmp_path_factory.mktemp("examples")
    obj = pebble(subdivisions=2)
    mesh_path = root / "pebble.ply"
    write_vertex_coloured_ply(mesh_path, obj.mesh)
    mesh = load_mesh(mesh_path)
    write_regions(root / "regions.json", mesh, segment(mesh), mesh_name="pebble.ply", regions_requested=None)
    plan_path = root / "plan.json"
    plan_path.write_bytes(plan_file[0].read_bytes())
    session = root / "session"
    session.mkdir()
    start_or_resume(session, plan_path, "a" * 64, rig, force=False)
    materials = {
        "format": "hlr-lab.materials", "version": 1, "model": "blinn-phong", "mesh": "pebble.ply",
        "regions": [{"id": 0, "color": [200, 50, 40], "vertices": 10, "rd": [0.5, 0.1, 0.1],
                     "rd_se": [0.001, 0.001, 0.001], "rs": [0.2, 0.2, 0.2], "rs_se": [0.01, 0.01, 0.01],
                     "n": 40.0, "n_se": 1.0, "specular": "measured", "theta_c_deg": 5.0,
                     "pixels": {"diffuse": 100, "highlight": 50}, "residual_rms": 0.01, "estimator": "robust"}],
    }  # fmt: skip
    scene = f'[object]\nmesh = "{mesh_path.name}"\n'
    for colour in ((200, 50, 40), (60, 160, 70)):
        scene += (
            f"\n[[region]]\ncolor = {list(colour)}\nrd = [0.5, 0.2, 0.1]\nrs = [0.2, 0.2, 0.2]\nn = 40.0\n"
        )
    scene += '\n[light]\ntype = "point"\npower = 1.0\n'
    campaign = (f'[campaign]\nname = "night"\n\n[[job]]\nname = "j0"\nplan = "{plan_path}"\nout = "s0"\nsim = true\n'
                f'speed_factor = 40\nlamp_every = 5\n\n[[job]]\nkind = "calibrate"\nname = "c"\n'
                'procedure = "radiometric"\nsim = true\noutput = "rig-r.toml"\n')  # fmt: skip
    return {
        "root": root,
        "mesh": mesh,
        "mesh_ply": mesh_path.read_bytes(),
        "mesh_obj": _obj_text(obj.mesh).encode(),
        "regions": json.loads((root / "regions.json").read_text()),
        "plan": json.loads(plan_path.read_text()),
        "materials": materials,
        "session": json.loads((session / SESSION).read_text()),
        "scene": scene,
        "campaign": campaign,
        "rig": (resources.files("hlr_lab.data") / "sim-rig.toml").read_text(),
    }


def _obj_text(mesh) -> str:
    """A vertex-coloured OBJ (`v x y z r g b`), as many tools write them."""
    v = [f"v {x:.6f} {y:.6f} {z:.6f} {r / 255:.4f} {g / 255:.4f} {b / 255:.4f}"
         for (x, y, z), (r, g, b) in zip(mesh.vertices, mesh.vertex_colours, strict=True)]  # fmt: skip
    return "\n".join(v + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]) + "\n"


def _write(examples: dict, name: str, data: bytes) -> Path:
    path = examples["root"] / name
    path.write_bytes(data)
    return path


# --- one property per format ---------------------------------------------------------------------------


@pytest.mark.slow
@BROKEN
@given(data=st.data())
def test_a_broken_plan_is_read_or_refused_in_one_line(examples, rig, data):
    path = _write(examples, "broken-plan.json", data.draw(mutated_json(examples["plan"])))
    with contextlib.suppress(InputError):
        motion_targets(read_plan(path), rig, path)  # what acquire does next with a plan it has read


@pytest.mark.slow
@BROKEN
@given(data=st.data())
def test_broken_regions_are_read_or_refused_in_one_line(examples, data):
    path = _write(examples, "broken-regions.json", data.draw(mutated_json(examples["regions"])))
    with contextlib.suppress(InputError):
        read_regions(path, examples["mesh"])


@pytest.mark.slow
@BROKEN
@given(data=st.data())
def test_broken_materials_are_read_or_refused_in_one_line(examples, data):
    path = _write(examples, "broken-materials.json", data.draw(mutated_json(examples["materials"])))
    try:
        materials = read_materials(path)
    except InputError:
        return
    for e in materials.regions:  # what a reader may rely on once it is read
        assert all(math.isfinite(v) and 0 <= v <= 1.5 for v in e.rd)
        assert e.n is None or (math.isfinite(e.n) and e.n > 0)


@pytest.mark.slow
@BROKEN
@given(data=st.data())
def test_a_broken_session_record_is_read_or_refused_in_one_line(examples, data):
    session = examples["root"] / "session"
    (session / SESSION).write_bytes(data.draw(mutated_json(examples["session"])))
    with contextlib.suppress(InputError):
        session_plan(session, read_record(session))


@pytest.mark.slow
@BROKEN
@given(data=st.data())
def test_a_broken_rig_file_is_read_or_refused_in_one_line(examples, data):
    path = _write(examples, "broken-rig.toml", data.draw(mutated_toml(examples["rig"])))
    try:
        rig = load_rig(path)
    except InputError:
        return
    assert rig.camera.width > 0
    assert rig.gantry.arm_radius > 0


@pytest.mark.slow
@BROKEN
@given(data=st.data())
def test_a_broken_campaign_is_read_or_refused_in_one_line(examples, data):
    path = _write(examples, "broken-night.toml", data.draw(mutated_toml(examples["campaign"])))
    with contextlib.suppress(InputError):
        load_campaign(path)


@pytest.mark.slow
@BROKEN
@given(data=st.data())
def test_a_broken_scene_is_read_or_refused_in_one_line(examples, data):
    path = _write(examples, "broken-scene.toml", data.draw(mutated_toml(examples["scene"])))
    try:
        scene = load_scene(path)
    except SceneError:
        return
    assert all(0 <= v <= 1 for m in scene.materials for v in (*m.rd, *m.rs))
    assert all(m.n > 0 for m in scene.materials)


@pytest.mark.slow
@BROKEN
@given(data=st.data(), kind=st.sampled_from(["obj", "ply"]))
def test_a_broken_mesh_is_read_or_refused_in_one_line(examples, data, kind):
    source = examples[f"mesh_{kind}"]
    how = data.draw(st.sampled_from(["random", "damaged", "edited"]))
    if how == "random":
        broken = data.draw(st.binary(max_size=400))
    elif how == "damaged" or kind == "ply":
        broken = _damaged(data.draw, source)
    else:  # a value changed inside the text: nan, huge, negative, missing
        lines = source.decode().splitlines()
        i = data.draw(st.integers(0, len(lines) - 1))
        words = lines[i].split()
        j = data.draw(st.integers(0, len(words) - 1))
        words[j] = data.draw(
            st.sampled_from(["nan", "inf", "1e400", "-1", "0", "x", "99999999", "1/2/3", ""])
        )
        lines[i] = " ".join(words)
        broken = "\n".join(lines).encode()
    path = _write(examples, f"broken.{kind}", broken)
    try:
        mesh = load_mesh(path, need_colour=True)
    except InputError:
        return
    assert np.isfinite(mesh.vertices).all()
    assert len(mesh.faces) > 0


@pytest.mark.slow
@BROKEN
@given(data=st.data())
def test_a_broken_journal_and_sidecar_are_set_aside_with_a_reason(examples, data):
    """A journal of frame lines and their sidecars, one sidecar rewritten (its checksum in the journal
    updated, as a careful hostile hand would) and the journal's lines mutated: loading sets bad lines
    aside and the fit's view of the frames refuses bad sidecars, with a reason each; nothing raises."""
    session = Path(tempfile.mkdtemp(dir=examples["root"], prefix="session-"))  # each example its own
    fields = {"pose": "p000", "exposure_index": 0, "dark": False, "exposure_s": 0.01}
    sidecar = {**fields, "gain_db": 0.0, "bits": 12, "captured_at": 1.0, "adaptive": False,
               "measured": {"turntable_steps": 0, "gantry_ticks": [2048, 1024]},
               "commanded": {"turntable_steps": 0, "gantry_ticks": [2048, 1024]}}  # fmt: skip
    stored = store_frame(
        session, f"f{data.draw(st.integers(0, 10**9))}", np.zeros((4, 5, 3), np.uint16), sidecar
    )
    event = {"event": "frame", **fields, "adaptive": False, "clipped_pixels": 0, **stored.files()}
    on_disk = json.loads((session / event["sidecar"]).read_text())
    rewritten = data.draw(mutated_json(on_disk))
    (session / event["sidecar"]).write_bytes(rewritten)
    event["sidecar_sha256"] = hashlib.sha256(rewritten).hexdigest()
    lines = [json.dumps(event).encode()] + [data.draw(mutated_json(event)) for _ in range(2)]
    (session / "journal.jsonl").write_bytes(b"\n".join(line.replace(b"\n", b" ") for line in lines) + b"\n")
    contents = load_journal(session / "journal.jsonl")
    views, rejected = _views(session, contents.events, {"p000"})
    assert len(views) + len(rejected) >= 1 or contents.damaged
