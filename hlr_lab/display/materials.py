"""A fit's progress, and the fitted materials as ``fit`` and ``demo`` show them."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TaskID, TextColumn
from rich.table import Table

from hlr_lab.formats.materials import MaterialsFile
from hlr_lab.reflectance.session_fit import FitResult, FitStep


def materials_table(materials: MaterialsFile) -> Table:
    """One row per region: Rd (linear RGB), Rs and n each ± statistical standard error ± systematic (where
    propagated; or why the lobe is unmeasured), θc (°), and the diffuse / highlight pixels used."""
    systematic = any(e.rd_sys is not None for e in materials.regions)
    title = (
        "fitted materials (± statistical ± systematic)"
        if systematic
        else "fitted materials (± standard error)"
    )
    t = Table(title=title, title_justify="left")
    for column in ("region", "Rd (linear RGB)", "Rs", "n", "θc", "pixels diffuse / highlight"):
        t.add_column(
            column, justify="right", overflow="fold"
        )  # a narrow terminal wraps, never cuts, a number
    for e in materials.regions:
        rd = " ".join(
            _value(v, s, y, 4) for v, s, y in zip(e.rd, e.rd_se, e.rd_sys or [None] * 3, strict=True)
        )
        if e.specular == "measured":
            # materials.json's model: a measured lobe has rs, rs_se, n, n_se
            assert e.rs is not None
            assert e.rs_se is not None
            assert e.n is not None
            assert e.n_se is not None
            rs = " ".join(
                _value(v, s, y, 4) for v, s, y in zip(e.rs, e.rs_se, e.rs_sys or [None] * 3, strict=True)
            )
            n = _value(e.n, e.n_se, e.n_sys, 2)
        else:
            rs, n = "unmeasured", escape(e.reason or "")
        theta = f"{e.theta_c_deg:.1f}°" if e.specular == "measured" else "—"  # an unmeasured lobe has none
        t.add_row(str(e.id), rd, rs, n, theta, f"{e.pixels.diffuse} / {e.pixels.highlight}")
    return t


def fit_notes(result: FitResult) -> list[str]:
    """What a fit says beside its table, as console markup: what the systematic errors leave out, the black
    level and the placement the photographs contradict, then each region with no entry and why. ``fit``
    and ``demo`` print the same lines."""
    lines = []
    systematic = result.materials.systematic
    for left_out in (systematic.uncalibrated, systematic.placement) if systematic is not None else ():
        if left_out:
            lines.append(f"[yellow]systematic:[/] {escape(left_out)}")
    if "warning" in result.diagnostics["black_level"]:
        lines.append(f"[yellow]warning:[/] {escape(result.diagnostics['black_level']['warning'])}")
    if "warning" in result.diagnostics["alignment"]:
        lines.append(f"[bold red]misplaced:[/] {escape(result.diagnostics['alignment']['warning'])}")
    for d in result.diagnostics["regions"]:
        if "note" in d:
            lines.append(f"[yellow]region {d['id']}: {escape(d['note'])}[/] (no entry written)")
    return lines


def _value(v: float, se: float, sys: float | None, digits: int) -> str:
    """``v±se`` and, where propagated, ``±sys``, to ``digits`` decimals."""
    return f"{v:.{digits}f}±{se:.{digits}f}" + ("" if sys is None else f"±{sys:.{digits}f}")


@contextlib.contextmanager
def stage_progress(console: Console) -> Iterator[Callable[[FitStep], None]]:
    """One bar per stage of a fit on ``console`` (HDR, G-buffer, …, each complete once the next starts);
    it gives the callable that :func:`hlr_lab.pipeline.fit_into` reports each step to."""
    columns = (
        TextColumn("{task.fields[stage]:8}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.description}"),
    )
    with Progress(*columns, console=console, transient=True) as bar:
        tasks: dict[str, TaskID] = {}

        def show(step: FitStep) -> None:
            if step.stage not in tasks:
                tasks[step.stage] = bar.add_task("", total=step.total, stage=step.stage)
            for stage, task in tasks.items():  # an earlier stage is complete once a later one starts
                if stage != step.stage:
                    bar.update(task, completed=bar.tasks[task].total)
            bar.update(tasks[step.stage], completed=step.index, description=escape(step.label))

        yield show
