"""Shared fixtures: the assets beside the checkout (skipped where absent) and a guard against leaked threads."""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

from hlr_lab.formats.plan import build_plan, write_plan
from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.object.procedural import ProceduralObject, pebble
from hlr_lab.object.segment import segment
from hlr_lab.planning.geometry import placement
from hlr_lab.planning.planner import PlanSettings, plan_lights
from hlr_lab.rig.file import Rig, sim_rig
from tests.films import resume_command
from tests.renderer_guard import require_aravis, require_renderer

# generated broken files (tests/test_readers_property.py): a CI-sized run, or the nightly one
settings.register_profile("ci", max_examples=150, database=None)
settings.register_profile("nightly", max_examples=10_000, database=None)
settings.load_profile(os.environ.get("HLR_LAB_HYPOTHESIS", "ci"))

SHARED_ASSETS = Path(__file__).resolve().parents[1].parent / "shared" / "assets"


_LOCKS: list[str] = []  # the lock folder this process made (the controller's and each worker's)


def pytest_configure(config):
    """Device locks of the tests (and of the hlr-lab processes they start) in a folder of their own; one
    BLAS thread per process."""
    _LOCKS.append(tempfile.mkdtemp(prefix="hlr-lab-test-locks-"))
    os.environ["HLR_LAB_LOCK_DIR"] = _LOCKS[-1]
    # Three workers on two cores (scripts/test), each with subprocesses: OpenBLAS's threads, two a process,
    # spin while they wait for work and took a sixth of the suite's CPU (1 420 → 1 173 CPU-s, 727 → 622 s of
    # wall clock, 2026-12-08). Set here, before the workers and the processes the tests start import numpy;
    # a value in the environment is kept.
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
        os.environ.setdefault(name, "1")


def pytest_unconfigure(config):
    """The lock folder goes with the run (every pytest process used to leave one in /tmp)."""
    for folder in _LOCKS:
        shutil.rmtree(folder, ignore_errors=True)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The longest modules first: with ``--dist loadfile`` (scripts/test) a worker takes a module whole,
    in this order, and a long module begun last keeps the suite waiting on one worker while the others
    idle. First the modules with a test marked with its own (longer) timeout, then those with a ``slow``
    test, then the rest; each module's tests, and the modules within a group, in their order."""
    rank: dict[str, int] = {}
    for item in items:
        here = 0 if item.get_closest_marker("timeout") else 1 if item.get_closest_marker("slow") else 2
        rank[item.location[0]] = min(rank.get(item.location[0], 2), here)
    items.sort(key=lambda item: rank[item.location[0]])


def pytest_runtest_setup(item: pytest.Item) -> None:
    """A test marked ``renderer`` is skipped where Mitsuba, libLLVM or Aravis is missing, one marked
    ``genicam`` where Aravis is (failed in CI)."""
    if item.get_closest_marker("renderer"):
        require_renderer()
    if item.get_closest_marker("genicam"):
        require_aravis()


@pytest.fixture(autouse=True)
def no_leaked_threads():
    before = set(threading.enumerate())
    yield
    new = [t for t in threading.enumerate() if t not in before]
    for t in new:  # threads told to stop (rich's refresh thread, say) get a moment to finish
        t.join(timeout=2.0)
    leaked = [t for t in new if t.is_alive()]
    assert not leaked, f"the test left threads running: {leaked}"


@pytest.fixture
def small_disk(tmp_path):
    """A function mounting a tmpfs of ``megabytes`` under tmp_path (``read_only``: empty and read-only;
    ``filled_from``: a copy of that folder, then made read-only); unmounted after the test. Needs root,
    which CI has (these tests fail there rather than skip)."""
    mounted = []

    def mount(megabytes: int, *, read_only: bool = False, filled_from: Path | None = None) -> Path:
        if os.geteuid() != 0:
            if os.environ.get("CI"):
                pytest.fail("the disk-full tests mount a tmpfs and need root, which CI has")
            pytest.skip("mounting a small tmpfs needs root")
        where = tmp_path / f"disk{len(mounted)}"
        where.mkdir()
        options = f"size={megabytes}m" + (",ro" if read_only else "")
        subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)], check=True)
        mounted.append(where)
        if filled_from is not None:
            shutil.copytree(filled_from, where, dirs_exist_ok=True)
            subprocess.run(["mount", "-o", "remount,ro", str(where)], check=True)
        return where

    yield mount
    for where in mounted:
        subprocess.run(["umount", "-l", str(where)], check=False)


@pytest.fixture(scope="session")
def assets() -> Path:
    if not SHARED_ASSETS.is_dir():
        pytest.skip("../shared/assets is not present")
    return SHARED_ASSETS


@pytest.fixture(scope="session")
def bunny_path(assets) -> Path:
    return assets / "stanford-bunny.obj"


@pytest.fixture(scope="session")
def spot_paths(assets) -> tuple[Path, Path]:
    return assets / "spot" / "spot_triangulated.obj", assets / "spot" / "spot_texture.png"


@pytest.fixture(scope="session")
def rig() -> Rig:
    return sim_rig()


@pytest.fixture(scope="session")
def pebble_object() -> ProceduralObject:
    return pebble()


@pytest.fixture(scope="session")
def placed_pebble(pebble_object) -> ColouredMesh:
    return pebble_object.mesh.transformed(placement(pebble_object.mesh))


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """True when two labelings split the items identically (up to renaming the labels)."""
    pairs = set(zip(a.tolist(), b.tolist(), strict=True))
    return len(pairs) == len(set(a.tolist())) == len(set(b.tolist()))


@pytest.fixture(scope="session")
def plan_file(tmp_path_factory, rig):
    """A small pebble plan on the simulated rig: (path, PlanResult, object, mesh→turntable)."""
    obj = pebble(subdivisions=4)
    seg = segment(obj.mesh)
    m = placement(obj.mesh)
    result = plan_lights(
        obj.mesh.transformed(m),
        seg,
        rig,
        PlanSettings(views_deg=[0.0, 90.0], spacing_deg=1.0, compare_criteria=False),
    )
    plan = build_plan(
        result,
        seg,
        mesh_ref="builtin:pebble",
        sha256=obj.mesh.sha256,
        texture_ref=None,
        texture_sha256=None,
        mesh_to_turntable=m,
        up="z",
        scale=1.0,
        exposures_s=rig.exposure_bracket_s,
        rig_name=rig.name,
    )
    path = tmp_path_factory.mktemp("plan") / "plan.json"
    write_plan(path, plan)
    return path, result, obj, m


@pytest.fixture(scope="session")
def builtin_plan(tmp_path_factory) -> Path:
    """A plan of builtin:pebble, the object the default simulated world is made of, as `hlr-lab plan`
    writes it."""
    from hlr_lab.cli.main import main

    path = tmp_path_factory.mktemp("builtin") / "plan.json"
    assert main(["plan", "--mesh", "builtin:pebble", "--sim", "-o", str(path)]) == 0
    return path


@pytest.fixture(scope="session")
def quarter_rig(tmp_path_factory) -> Path:
    """The simulated rig's drawing with its camera at 640×480 (tests.films): ``--rig`` it with ``--sim`` and
    the world is that rig too — a quarter of the pixels to render and fit, where the image is not the
    subject."""
    from tests.films import DRAWING, half_film

    path = tmp_path_factory.mktemp("quarter-rig") / "rig.toml"
    path.write_text(half_film(DRAWING.read_text()))
    return path


@pytest.fixture(scope="session")
def finished_session(builtin_plan, quarter_rig, tmp_path_factory) -> Path:
    """A complete session of the built-in plan on the simulated rig at a quarter of its pixels (tests copy
    it before changing it; a resume names the same rig: ``resume_command``)."""
    from hlr_lab.cli.main import main

    session = tmp_path_factory.mktemp("finished") / "session"
    command = resume_command(builtin_plan, quarter_rig, session)
    assert main(command) == 0
    return session
