"""The soak (``hlr-lab bench soak``) at a CI size: faults of every kind, SIGKILLs, resumes, and at the end
every planned frame once and intact, no goal outside the limits, flat memory and descriptors.

HLR_LAB_SOAK_POSES and HLR_LAB_SOAK_KILLS size it (20 and 2 here: a leak of one descriptor or one frame a
pose still shows as 8 over the leak window; a nightly-sized run: 500 and 10,
whose figures are in the README)."""

from __future__ import annotations

import os

import pytest

from benchmarks.soak import leak_window, soak

pytestmark = pytest.mark.renderer  # the simulated rig renders its frames

POSES = int(os.environ.get("HLR_LAB_SOAK_POSES", "20"))
KILLS = int(os.environ.get("HLR_LAB_SOAK_KILLS", "2"))


@pytest.mark.slow
@pytest.mark.timeout(max(1200, 8 * POSES))  # 77 s: 2 cores, one kept busy, 3 workers
def test_a_soak_with_faults_and_kills_ends_with_every_frame_once(rig):
    f = soak(poses=POSES, kills=KILLS, fault_interval_s=0.4, speed_factor=1000.0, seed=7)
    assert f.frames_journaled == f.frames_planned
    assert (f.duplicates, f.damaged, f.goals_outside) == (0, 0, 0)
    assert f.ends["killed"] == KILLS
    assert f.ends["complete"] == 1
    assert sum(f.faults.values()) >= POSES // 2
    assert f.retries_journaled > 0
    warm, late = leak_window(f.longest_child)
    assert late.fds <= warm.fds + 2  # a leak of one descriptor per pose would show as dozens
    assert late.rss_mb <= warm.rss_mb + 60  # a frame (7.4 MB) kept per pose would show as hundreds
