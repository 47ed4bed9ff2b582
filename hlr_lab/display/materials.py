"""A fit's progress, and the fitted materials as ``fit`` and ``demo`` show them."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TaskID, TextColumn
from rich.table import Table

from hlr_lab.formats.materials import MaterialsFile
from hlr_lab.reflectance.session_fit import FitStep


def materials_table(materials: MaterialsFile) -> Table:
    """One row per region: Rd (linear RGB) ± SE, Rs, n ± SE (or why the lobe is unmeasured), θc (°), and
    the diffuse / highlight pixels used."""
    t = Table(title="fitted materials (± standard error)", title_justify="left")
    for column in ("region", "Rd (linear RGB)", "Rs", "n", "θc", "pixels diffuse / highlight"):
        t.add_column(column, justify="right")
    for e in materials.regions:
        rd = " ".join(f"{v:.4f}±{s:.4f}" for v, s in zip(e.rd, e.rd_se, strict=True))
        if e.specular == "measured":
            assert e.rs is not None  # materials.json's model: a measured lobe has rs, rs_se, n, n_se
            assert e.n is not None
            rs = " ".join(f"{v:.4f}" for v in e.rs)
            n = f"{e.n:.1f}±{e.n_se:.1f}"
        else:
            rs, n = "unmeasured", escape(e.reason or "")
        theta = f"{e.theta_c_deg:.1f}°" if e.specular == "measured" else "—"  # an unmeasured lobe has none
        t.add_row(str(e.id), rd, rs, n, theta, f"{e.pixels.diffuse} / {e.pixels.highlight}")
    return t


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
