"""``glacimap`` command line: one module per command, all over the public library API."""

from __future__ import annotations

import inspect
import os
import sys

import typer
from rich.console import Console
from rich.markup import escape

from terrain.errors import GlacimapError

from . import (
    certify,
    change,
    export,
    localize,
    plan,
    process,
    reconstruct,
    report,
    run,
    simulate,
    sweep,
)
from ._interrupt import catching_ctrl_c, interrupted

app = typer.Typer(
    name="glacimap",
    help="Certified, probabilistic elevation maps of glaciers from a rover survey.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _print_version(value: bool) -> None:
    if value:
        from .. import __version__

        typer.echo(f"glacimap {__version__}")
        raise typer.Exit(0)


@app.callback()
def _root(
    version: bool = typer.Option(
        False,
        "--version",
        callback=_print_version,
        is_eager=True,
        help="Print the installed glacimap version (what certificates record) and exit.",
    ),
) -> None:
    """Certified, probabilistic elevation maps of glaciers from a rover survey."""


#: One line per command for ``glacimap --help`` (typer would list the whole first paragraph
#: of each docstring with its hard line breaks); ``glacimap COMMAND --help`` gives the rest.
COMMANDS = (
    (
        "run",
        run.run_command,
        "The main job: simulate a survey and process it to certified products.",
    ),
    (
        "process",
        process.process_command,
        "A real survey's files (field folder, DEM, control, checkpoints) to certified products.",
    ),
    (
        "plan",
        plan.plan_command,
        "Plan a survey (lawnmower or piecewise continuous) and score its coverage.",
    ),
    (
        "simulate",
        simulate.simulate_command,
        "Simulate a rover traverse: its measurement log or a field folder.",
    ),
    (
        "localize",
        localize.localize_command,
        "Fuse a measurement log in iSAM2 and select landmarks (samples.csv).",
    ),
    (
        "reconstruct",
        reconstruct.reconstruct,
        "A map (mean and 1-sigma) from samples.csv with a Gaussian process.",
    ),
    (
        "sweep",
        sweep.sweep_command,
        "Random terrains: the fewest swaths per mapping class (Fig. 10-11).",
    ),
    ("export", export.export_command, "A terrain product to COG, contours and mesh."),
    (
        "certify",
        certify.certify_command,
        "Certify any DEM's vertical accuracy against independent checkpoints.",
    ),
    (
        "report",
        report.report_command,
        "Rebuild the self-contained HTML report of a run or a certified DEM.",
    ),
    (
        "change",
        change.change_command,
        "Elevation and volume change between two DEMs, with an error budget.",
    ),
)


def command_help(fn) -> str:
    """A command's docstring as ``--help`` shows it: each paragraph on one line (rich wraps
    it to the terminal). Typer >= 0.20 joins the first paragraph's lines but keeps the hard
    line breaks of the others, which printed them cut mid-sentence (``glacimap change``)."""
    paragraphs = inspect.cleandoc(fn.__doc__ or "").split("\n\n")
    return "\n\n".join(" ".join(par.split()) for par in paragraphs)


for _name, _fn, _short in COMMANDS:
    app.command(_name, short_help=_short, help=command_help(_fn))(_fn)

err_console = Console(stderr=True)


INTERRUPTED = 130
"""Exit code of a command stopped by Ctrl-C (SIGINT): 128 + signal 2, the shell convention."""


def main() -> None:
    """Entry point: library errors become one clear line and exit code 2 (bad input); Ctrl-C
    exits 130 with one line; every other exit code a command sets is passed on."""
    with catching_ctrl_c() as ctrl_c:
        rc = _run_app()
    if ctrl_c.came:  # whatever the command did with the Ctrl-C on its way (_interrupt)
        rc = INTERRUPTED
    # Without standalone mode typer *returns* the exit code of ``typer.Exit`` and turns
    # KeyboardInterrupt into Exit(130) (typer.core._main): it must reach the shell.
    if rc == INTERRUPTED:
        err_console.print(
            "[yellow]interrupted (Ctrl-C):[/] stopped; no file is left half-written "
            "(every write is atomic)",
            soft_wrap=True,
        )
        leave_now(INTERRUPTED)
    sys.exit(rc if isinstance(rc, int) else 0)


def _run_app() -> int | None:
    """The command's exit code; a library error exits 2 here with one line."""
    try:
        return app(standalone_mode=False)
    except GlacimapError as exc:
        # escape: messages quote user values, and "[table]" would read as rich markup
        # soft_wrap: one line however narrow the terminal (or 80 columns in a pipe), so that
        # scripts and logs read the error as the README promises
        err_console.print(f"[bold red]error:[/] {escape(str(exc))}", soft_wrap=True)
        sys.exit(2)
    except (typer.Abort, KeyboardInterrupt):
        return INTERRUPTED
    except typer.Exit as exc:
        return exc.exit_code
    except Exception as exc:  # click usage errors carry their own exit code
        if interrupted():  # e.g. ImportError from a module the Ctrl-C cut short
            return INTERRUPTED
        if isinstance(exc, _click_exceptions()):
            exc.show()
            sys.exit(exc.exit_code)
        raise


def leave_now(code: int) -> None:
    """End the process with ``code`` at once, skipping the interpreter's teardown.

    After Ctrl-C every product has already been rolled back: the ``with`` blocks that write
    (:func:`terrain.atomic.atomic_path`) and that own a Dask cluster ran on the way here. What
    is left is the teardown, which joins the worker threads of any pool the interrupt cut
    short; a worker waiting on a lock the interrupted main thread never released would keep
    the process alive for ever (``tests/test_cli_signals.py`` builds that case). A user who
    pressed Ctrl-C wants the prompt back, so nothing is waited for.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _click_exceptions() -> tuple[type[Exception], ...]:
    """``ClickException`` of click and of the copy of click that typer >= 0.22 vendors (its
    usage errors are not ``click.ClickException`` instances)."""
    found = [c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException"]
    try:
        import click

        found.append(click.ClickException)
    except ImportError:  # typer without the click distribution
        pass
    return tuple(found)
