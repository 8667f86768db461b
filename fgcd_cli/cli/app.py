"""The ``fgcd`` command: one typer app, errors mapped to exit codes here only."""

from __future__ import annotations

import os
import sys

import typer

from fgcd_cli import __version__
from fgcd_cli.cli.output import state
from fgcd_cli.errors import FgcdError

app = typer.Typer(
    name="fgcd",
    help="Fine-grained change detection of cultural heritage: calibrate, capture, relocate, diff.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _root(
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Print debugging detail."),
    version: bool = typer.Option(False, "--version", help="Print the version and exit."),
) -> None:
    """fgcd: fine-grained change detection with active camera relocalization."""
    state.verbose = verbose
    if version:
        print(f"fgcd {__version__}")
        raise typer.Exit(0)


def _register() -> None:
    """Attach every command group. Only commands that work are registered."""
    from fgcd_cli.cli import campaign_cmd

    app.add_typer(campaign_cmd.app, name="campaign")
    from fgcd_cli.cli import capture_cmd, demo_cmd

    app.command(name="capture")(capture_cmd.capture)
    app.command(name="relocate")(capture_cmd.relocate)
    app.command(name="demo")(demo_cmd.demo)
    from fgcd_cli.cli import afd_cmd, diff_cmd, report_cmd

    app.command(name="afd")(afd_cmd.afd)
    app.command(name="diff", help=diff_cmd.HELP)(diff_cmd.diff)
    app.command(name="report")(report_cmd.report)
    from fgcd_cli.cli import bench_cmd

    app.add_typer(bench_cmd.app, name="bench")
    from fgcd_cli.cli import calibrate_cmd

    app.add_typer(calibrate_cmd.app, name="calibrate")
    from fgcd_cli.cli import sim_cmd

    app.add_typer(sim_cmd.app, name="sim")
    from fgcd_cli.cli import platform_cmd

    app.add_typer(platform_cmd.app, name="platform")


_register()

# Exit codes for failures that do not come from fgcd_cli.errors.
EXIT_PLATFORM = 7
EXIT_INTERRUPTED = 130


def _platform_error_type():
    try:
        from drivers.platform import PlatformError

        return PlatformError
    except Exception:  # pragma: no cover - drivers always ship with fgcd
        return ()


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def _fail(prefix: str, exc: object, code: int) -> None:
    # Plain print: one unwrapped line whatever the terminal width.
    print(f"{prefix}: {_one_line(exc)}", file=sys.stderr)
    sys.exit(code)


def main() -> None:
    """Console-script entry point: run the app, turn expected failures into one line."""
    try:
        _main()
    except SystemExit as exc:
        if _abandoned_native_threads():
            # A hung UR controller left ur_rtde threads reconnecting forever inside
            # native code: a normal interpreter exit would wait for them.
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
        raise


def _abandoned_native_threads() -> bool:
    ur = sys.modules.get("drivers.ur")
    return bool(getattr(ur, "_ABANDONED", None))


def _main() -> None:
    platform_error = _platform_error_type()
    try:
        # without standalone mode typer *returns* the exit code of typer.Exit / Ctrl-C
        code = app(standalone_mode=False)
        if isinstance(code, int) and code:
            sys.exit(code)
    except FgcdError as exc:
        _fail("error", exc, exc.exit_code)
    except platform_error as exc:  # type: ignore[misc]
        _fail("platform error", exc, EXIT_PLATFORM)
    except KeyboardInterrupt:
        _fail("interrupted", "stopped by the user", EXIT_INTERRUPTED)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.Abort:
        _fail("aborted", "by the user", 1)
    except Exception as exc:
        # typer vendors click: usage errors carry show() and exit_code.
        if hasattr(exc, "show") and hasattr(exc, "exit_code") and hasattr(exc, "format_message"):
            _fail("usage error", exc.format_message(), int(exc.exit_code))
        if isinstance(exc, OSError):
            _fail("error", f"{exc.strerror or exc}: {getattr(exc, 'filename', '') or ''}", 1)
        if state.verbose:
            raise
        _fail("internal error", f"{type(exc).__name__}: {exc} (run with --verbose for details)", 70)


if __name__ == "__main__":
    main()
