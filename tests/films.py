"""The simulated rig's drawing at a quarter of its pixels: for tests whose subject is not the image (a
campaign's jobs, a stop, a damaged journal), and for those that measure the lamp or the radiometry
rather than the film (the sensitivity is per pixel)."""

from __future__ import annotations

from pathlib import Path

DRAWING = Path(__file__).resolve().parents[1] / "hlr_lab" / "data" / "sim-rig.toml"
FULL_FILM = (
    "width = 1280\nheight = 960\n",
    "matrix = [[2400.0, 0.0, 643.5], [0.0, 2400.0, 476.0], [0.0, 0.0, 1.0]]",
)
HALF_FILM = (
    "width = 640\nheight = 480\n",
    "matrix = [[1200.0, 0.0, 321.75], [0.0, 1200.0, 238.0], [0.0, 0.0, 1.0]]",
)


def half_film(text: str) -> str:
    """A rig file's text with the simulated rig's camera at 640×480 (the same lens: K halved), a quarter
    of the pixels to render, sense and fit."""
    for full, half in zip(FULL_FILM, HALF_FILM, strict=True):
        assert full in text
        text = text.replace(full, half)
    return text


def resume_command(plan: Path, rig: Path, session: Path, speed_factor: float = 40) -> list[str]:
    """``hlr-lab acquire`` of ``plan`` into ``session`` on the simulated rig described by ``rig``: how
    ``finished_session`` was taken, and how a test resumes a copy of it."""
    return ["acquire", "--plan", str(plan), "--rig", str(rig), "--sim", "--out", str(session),
            "--speed-factor", f"{speed_factor:g}"]  # fmt: skip
