"""A headless Chromium for the report test: skipped where there is none — except in CI, which installs
it (scripts/setup), so that there a missing browser fails instead of passing silently."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest

NAMES = ("chromium", "chromium-browser", "google-chrome")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--allow-file-access-from-files"]


def chromium() -> str:
    found = next((p for p in map(shutil.which, NAMES) if p), None)
    if found is None:
        if os.environ.get("CI"):
            raise RuntimeError("no Chromium: scripts/setup installs it (apt-get install chromium)")
        pytest.skip("no headless Chromium here")
    return found


def screenshot(page: Path, png: Path, size=(1200, 2400)) -> None:
    subprocess.run(
        [chromium(), *FLAGS, f"--window-size={size[0]},{size[1]}", f"--screenshot={png}", page.as_uri()],
        check=True,
        capture_output=True,
        timeout=120,
    )


def dom_after_load(page: Path) -> str:
    """The page's DOM once loaded and its scripts run (what the browser made of the file)."""
    return subprocess.run(
        [chromium(), *FLAGS, "--virtual-time-budget=5000", "--dump-dom", page.as_uri()],
        check=True,
        capture_output=True,
        text=True,
        timeout=120,
    ).stdout
