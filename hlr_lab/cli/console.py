"""The consoles every command prints to (kept light: ``hlr-lab --help`` imports only this)."""

from __future__ import annotations

from rich.console import Console

console = Console(stderr=True, highlight=False)  # stdout stays clean for data; people read stderr
out = Console(highlight=False)
