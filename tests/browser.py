"""A headless Chromium for the report test: skipped where there is none — except in CI, which installs
it (scripts/setup), so that there a missing browser fails instead of passing silently."""

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

NAMES = ("chromium", "chromium-browser", "google-chrome")
# headless, as root, and quiet on a closed network (no background connections, no first-run work)
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--hide-scrollbars",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def chromium() -> str:
    found = next((p for p in map(shutil.which, NAMES) if p), None)
    if found is None:
        if os.environ.get("CI"):
            raise RuntimeError("no Chromium: scripts/setup installs it (apt-get install chromium)")
        pytest.skip("no headless Chromium here")
    return found


def _run(*args: str) -> str:
    with tempfile.TemporaryDirectory(prefix="hlr-chromium-") as profile:  # a new empty profile each time
        return subprocess.run(
            [chromium(), *FLAGS, f"--user-data-dir={profile}", *args],
            check=True,
            capture_output=True,
            text=True,
            timeout=120,
        ).stdout


def screenshot(page: Path, png: Path, size=(1200, 2400)) -> None:
    _run(f"--window-size={size[0]},{size[1]}", f"--screenshot={png}", page.as_uri())


def dom_after_load(page: Path) -> str:
    """The page's DOM once loaded and its scripts run (what the browser made of the file)."""
    return _run("--virtual-time-budget=5000", "--dump-dom", page.as_uri())
