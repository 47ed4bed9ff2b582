"""``hlr-lab``: one clear line per error, exit status ≠ 0, a traceback only with ``--debug``."""

from __future__ import annotations

import importlib
import logging
import sys
import warnings

import click
from rich.markup import escape

from hlr_lab import __version__
from hlr_lab.cli.console import console
from hlr_lab.errors import HlrLabError, os_error_line
from hlr_lab.instrument.signals import stop_once_on_signals

EXIT_ERROR = 1  # an HlrLabError: bad input, device trouble
EXIT_INTERRUPTED = 130  # Ctrl-C or a signal, and nothing left unsafe
EXIT_INTERNAL = 70  # a bug in hlr-lab (EX_SOFTWARE)
# their records go to a session's log (acquire.log); the console has its own lines for the operator
QUIET_LOGGERS = ("hlr_lab", "drivers", "pymodbus")

# name → (where the command lives, its one-line summary). A command's module is imported only when the
# command runs, so that `hlr-lab --help` and a typo answer at once instead of loading numpy, trimesh,
# scipy and the rest; a test keeps the summaries equal to the commands' own.
COMMANDS = {
    "paint": ("hlr_lab.cli.paint_cmd:paint",
              "Paint a mesh in K spatially compact patches of distinct colours, for trying segment, plan and "
              "the simulated rig on a mesh that has no colours of its own (the patches are k-means clusters "
              "of the vertices; the colours are far apart in CIELAB)."),
    "segment": ("hlr_lab.cli.segment_cmd:segment",
                "Split the surface into same-colour regions (per-vertex and per-face labels)."),
    "plan": ("hlr_lab.cli.plan_cmd:plan",
             "Plan as few light positions as it can that give every region M highlight samples."),
    "register": ("hlr_lab.cli.register_cmd:register",
                 "Photograph the object where it lies, measure its placement, and plan again for it."),
    "acquire": ("hlr_lab.cli.acquire_cmd:acquire_cmd",
                "Move to every pose of the plan, capture its exposure bracket, and journal every frame."),
    "fit": ("hlr_lab.cli.fit_cmd:fit",
            "Fit per-region Phong materials (Rd, Rs, n, each with its standard error) to a session's frames."),
    "report": ("hlr_lab.cli.report_cmd:report",
               "Write an HTML report of a fitted session: materials ± standard errors, the β–Is curves with "
               "the fitted lobes, each pose's photograph beside the fitted materials rendered back (with an "
               "error map and PSNR), the plan and the run summary."),
    "export": ("hlr_lab.cli.export_cmd:export", "Write the fitted materials on the mesh for other tools."),
    "bench": ("hlr_lab.cli.bench_cmd:bench", "Benchmarks that print figures (targets in the README)."),
    "sim": ("hlr_lab.cli.sim_cmd:sim",
            "The simulated rig (servo bus on a pseudo-terminal, Modbus turntable and lamp relay, camera)."),
    "calibrate": ("hlr_lab.cli.calibrate_cmd:calibrate",
                  "Measure the rig (camera, gantry, radiometric, or all) and write a calibrated copy of its rig file."),
    "campaign": ("hlr_lab.cli.campaign_cmd:campaign",
                 "Unattended campaigns: a night of jobs (acquire, calibrate) run one after another."),
    "doctor": ("hlr_lab.cli.doctor_cmd:doctor",
               "Connect to every device of the rig and report identities, limits, temperatures and alarms."),
    "demo": ("hlr_lab.cli.demo_cmd:demo",
             "Run the whole measurement on the simulated rig and compare the result with the truth."),
}  # fmt: skip


class LazyGroup(click.Group):
    """A group whose commands are imported when used (see :data:`COMMANDS`)."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name not in COMMANDS:
            return None
        module, _, attribute = COMMANDS[cmd_name][0].partition(":")
        return getattr(importlib.import_module(module), attribute)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        limit = formatter.width - 6 - max(map(len, COMMANDS))
        rows = [(name, _shortened(summary, limit)) for name, (_, summary) in COMMANDS.items()]
        with formatter.section("Commands"):
            formatter.write_dl(rows)


def _shortened(text: str, limit: int) -> str:
    if len(text) <= limit:
        return text
    return text[: limit - 3].rsplit(" ", 1)[0].rstrip(",;:") + "..."


@click.group(
    cls=LazyGroup,
    context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100, "show_default": True},
)
@click.version_option(__version__, prog_name="hlr-lab")
@click.option("--debug", is_flag=True, help="Show the full traceback of an error.")
@click.pass_context
def cli(ctx: click.Context, debug: bool) -> None:
    """hlr-lab: measure the reflectance of an object of known shape.

    \b
    Segment the mesh into same-colour regions, plan light positions that put highlights on as many
    regions as possible at once, and export fitted Phong materials for other tools.

    \b
    Example: the whole measurement on the built-in simulated rig and procedural object:
      hlr-lab demo --out demo
    """
    ctx.obj = {"debug": debug}


def main(argv: list[str] | None = None) -> int:
    """Run one command; the first SIGINT/SIGTERM stops it (exit status 130), later ones cannot cut its
    safe stop short (:mod:`hlr_lab.instrument.signals`)."""
    for name in QUIET_LOGGERS:
        logger = logging.getLogger(name)
        if not any(isinstance(h, logging.NullHandler) for h in logger.handlers):
            logger.addHandler(logging.NullHandler())
    with stop_once_on_signals(), warnings.catch_warnings():
        warnings.showwarning = _one_line_warning
        return _run(argv)


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A library's warning as one console line (Python's own shows the file, the line and its source:
    PIL's DecompressionBombWarning reads as a crash)."""
    text = str(message).strip().splitlines()[0] if str(message).strip() else category.__name__
    console.print(f"[yellow]warning:[/] {escape(text)}", soft_wrap=True)


def _run(argv: list[str] | None) -> int:
    debug = "--debug" in (argv if argv is not None else sys.argv[1:])
    try:
        return cli.main(args=argv, prog_name="hlr-lab", standalone_mode=False) or 0
    except click.exceptions.Abort:
        console.print("[red]interrupted[/]")
        return EXIT_INTERRUPTED
    except click.UsageError as exc:  # a wrong option or value: one line naming it, and where help is
        where = exc.ctx.command_path if exc.ctx is not None else "hlr-lab"
        console.print(
            f"[bold red]error:[/] {escape(exc.format_message().rstrip('.'))}; see {where} --help",
            soft_wrap=True,
        )
        return exc.exit_code
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code
    except HlrLabError as exc:
        if debug:
            console.print_exception()
        # a stopped run (hlr_lab.instrument.control.RunStopped) carries its own status: 130 when it was
        # stopped by a signal and the rig is confirmed safe
        status = getattr(exc, "exit_status", EXIT_ERROR)
        label = "[yellow]interrupted:[/]" if status == EXIT_INTERRUPTED else "[bold red]error:[/]"
        console.print(f"{label} {escape(str(exc))}", soft_wrap=True)  # "[lamp]" is no markup
        return status
    except (
        OSError
    ) as exc:  # the machine said no: a read-only folder, a directory where a file goes, a full disk
        if debug:
            console.print_exception()
        console.print(f"[bold red]error:[/] {escape(os_error_line(exc))}", soft_wrap=True)
        return EXIT_ERROR
    except Exception as exc:  # the last line of defence: a bug must still end in one clear line
        if debug:
            console.print_exception()
        console.print(
            f"[bold red]internal error:[/] {type(exc).__name__}: {escape(str(exc))} — please report it with the "
            "output of the same command run with --debug",
            soft_wrap=True,
        )
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
