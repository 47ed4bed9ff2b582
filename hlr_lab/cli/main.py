"""``hlr-lab``: one clear line per error, exit status ≠ 0, a traceback only with ``--debug``."""

from __future__ import annotations

import logging
import sys

import click
from rich.markup import escape

from hlr_lab import __version__
from hlr_lab.acquire_session import EXIT_INTERRUPTED, RunStopped
from hlr_lab.cli.acquire_cmd import acquire_cmd
from hlr_lab.cli.bench_cmd import bench
from hlr_lab.cli.common import console
from hlr_lab.cli.demo_cmd import demo
from hlr_lab.cli.doctor_cmd import doctor
from hlr_lab.cli.export_cmd import export
from hlr_lab.cli.fit_cmd import fit
from hlr_lab.cli.plan_cmd import plan
from hlr_lab.cli.report_cmd import report
from hlr_lab.cli.segment_cmd import segment
from hlr_lab.cli.sim_cmd import sim
from hlr_lab.errors import HlrLabError
from hlr_lab.signals import stop_once_on_signals

EXIT_ERROR = 1  # an HlrLabError: bad input, device trouble
EXIT_INTERNAL = 70  # a bug in hlr-lab (EX_SOFTWARE)


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="hlr-lab")
@click.option("--debug", is_flag=True, help="Show the full traceback of an error.")
@click.pass_context
def cli(ctx: click.Context, debug: bool) -> None:
    """hlr-lab: measure the reflectance of an object of known shape.

    \b
    Segment the mesh into same-colour regions, plan light positions that put highlights on as many
    regions as possible at once, and export fitted Phong materials for other tools.

    \b
    Example, on the built-in simulated rig and procedural object:
      hlr-lab plan --mesh builtin:pebble --sim -o plan.json
    """
    ctx.obj = {"debug": debug}


cli.add_command(segment)
cli.add_command(plan)
cli.add_command(acquire_cmd)
cli.add_command(fit)
cli.add_command(report)
cli.add_command(export)
cli.add_command(bench)
cli.add_command(sim)
cli.add_command(doctor)
cli.add_command(demo)


def main(argv: list[str] | None = None) -> int:
    """Run one command; the first SIGINT/SIGTERM stops it (exit status 130), later ones cannot cut its
    safe stop short (:mod:`hlr_lab.signals`)."""
    for name in (
        "hlr_lab",
        "drivers",
        "pymodbus",
    ):  # records go to the session's log; the console has its own
        logger = logging.getLogger(name)
        if not any(isinstance(h, logging.NullHandler) for h in logger.handlers):
            logger.addHandler(logging.NullHandler())
    with stop_once_on_signals():
        return _run(argv)


def _run(argv: list[str] | None) -> int:
    debug = "--debug" in (argv if argv is not None else sys.argv[1:])
    try:
        return cli.main(args=argv, prog_name="hlr-lab", standalone_mode=False) or 0
    except click.exceptions.Abort:
        console.print("[red]interrupted[/]")
        return EXIT_INTERRUPTED
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code
    except RunStopped as exc:  # a run that switched devices on: what stopped it and the rig's state
        if debug:
            console.print_exception()
        colour = "yellow" if exc.exit_status == EXIT_INTERRUPTED else "bold red"
        label = "interrupted" if exc.exit_status == EXIT_INTERRUPTED else "error"
        console.print(f"[{colour}]{label}:[/] {escape(str(exc))}", soft_wrap=True)
        return exc.exit_status
    except HlrLabError as exc:
        if debug:
            console.print_exception()
        console.print(f"[bold red]error:[/] {escape(str(exc))}", soft_wrap=True)  # "[lamp]" is no markup
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
