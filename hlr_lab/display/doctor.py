"""What ``doctor`` found, device by device."""

from __future__ import annotations

from rich.markup import escape
from rich.table import Table

from hlr_lab.instrument.doctor import Finding

MARKS = {"ok": "[green]ok[/]", "warning": "[yellow]warning[/]", "problem": "[bold red]problem[/]"}


def findings_table(name: str, findings: list[Finding]) -> Table:
    """One row per finding on rig ``name``: the device, its state, what it says and what to do."""
    table = Table(title=name, title_justify="left")
    for column in ("device", "state", "what it says / what to do"):
        table.add_column(column, overflow="fold")
    for f in findings:
        table.add_row(escape(f.device), MARKS[f.level], escape(f.message))
    return table
