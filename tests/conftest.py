"""Shared fixtures: the assets beside the checkout (skipped where absent) and a guard against leaked threads."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from hlr_lab.mesh import ColouredMesh
from hlr_lab.planning.geometry import placement
from hlr_lab.procedural import ProceduralObject, pebble
from hlr_lab.rig import Rig, sim_rig

SHARED_ASSETS = Path(__file__).resolve().parents[1].parent / "shared" / "assets"


@pytest.fixture(autouse=True)
def no_leaked_threads():
    before = set(threading.enumerate())
    yield
    new = [t for t in threading.enumerate() if t not in before]
    for t in new:  # threads told to stop (rich's refresh thread, say) get a moment to finish
        t.join(timeout=2.0)
    leaked = [t for t in new if t.is_alive()]
    assert not leaked, f"the test left threads running: {leaked}"


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
