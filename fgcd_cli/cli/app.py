"""The ``fgcd`` command: one typer app, errors mapped to exit codes here only.

Every failure is one line on stderr and a documented exit code; with ``--json``
the same line is also printed on stdout as ``{"error": ..., "code": ...}``
unless the command already printed its JSON result (one object on stdout).
"""

from __future__ import annotations

import os
import select
import signal
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import typer
import typer.main

from fgcd_cli import __version__
from fgcd_cli.cli.options import install_help_conventions
from fgcd_cli.cli.output import state, stdin_is_terminal, to_json
from fgcd_cli.errors import (
    OUT_OF_MEMORY,
    ConfirmationNeeded,
    FgcdError,
    StopSignal,
    is_out_of_memory,
    os_error_line,
    run_record,
)

install_help_conventions()  # plain-text help, no <bool> after a flag (every command)
app = typer.Typer(
    name="fgcd",
    help="Fine-grained change detection of cultural heritage: calibrate, capture, relocate, diff.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _print_version(value: bool) -> None:
    # Eager: runs while the options are parsed, before click asks for a command.
    if value:
        print(f"fgcd {__version__}")
        raise typer.Exit(0)


@app.callback()
def _root(
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Print debugging detail."),
    version: bool = typer.Option(
        False, "--version", help="Print the version and exit.", is_eager=True, callback=_print_version
    ),
) -> None:
    """fgcd: fine-grained change detection with active camera relocalization."""
    state.verbose = verbose


def _register() -> None:
    """Attach every command group. Only commands that work are registered."""
    from fgcd_cli.cli import campaign_cmd

    app.add_typer(campaign_cmd.app, name="campaign")
    from fgcd_cli.cli import capture_cmd, demo_cmd, relocate_cmd

    app.command(name="capture")(capture_cmd.capture)
    app.command(name="relocate")(relocate_cmd.relocate)
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
    from fgcd_cli.cli import archive_cmd

    app.add_typer(archive_cmd.app, name="archive")


try:
    _register()
except KeyboardInterrupt:  # Ctrl-C while the commands load: nothing has run yet
    print("interrupted (Ctrl-C): while starting; nothing was moved or written", file=sys.stderr)
    sys.exit(130)

# Exit codes (README "Errors"); FgcdError subclasses carry their own (2-7).
EXIT_ABORTED = 1  # no answer at a confirmation prompt (end of input on a terminal)
EXIT_OS = 1  # an operating-system error outside fgcd's own checks
EXIT_PLATFORM = 7
EXIT_INTERNAL = 70
EXIT_INTERRUPTED = 130


@dataclass(frozen=True)
class Failure:
    """How a command ended when it did not succeed: one line and an exit code."""

    prefix: str
    message: str
    code: int

    @property
    def line(self) -> str:
        """The one line printed on stderr (whitespace folded, whatever the message)."""
        return " ".join(f"{self.prefix}: {self.message}".split())


def main() -> None:
    """Console-script entry point: run the app, turn expected failures into one line."""
    from fgcd_cli.app.determinism import limit_blas_threads
    from fgcd_cli.cli.native_stderr import route_native_stderr

    route_native_stderr()  # native libraries' own lines go to a log: stderr stays one line
    limit_blas_threads()
    abandoned_before = _abandoned_native_interfaces()
    try:
        sys.exit(run(app, sys.argv[1:]))
    except SystemExit as exc:
        # Rule: only the command that abandoned interfaces ends the process at once; a
        # host process (a test session, a notebook) that abandoned some earlier goes on.
        if _abandoned_native_interfaces() > abandoned_before:
            # A hung UR controller left ur_rtde threads reconnecting forever inside
            # native code: a normal interpreter exit would wait for them.
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
        raise


def _abandoned_native_interfaces() -> int:
    ur = sys.modules.get("fgcd_drivers.ur")
    return 0 if ur is None else ur.abandoned_interface_count()


def run(typer_app: typer.Typer, args: Sequence[str]) -> int:
    """Run one command line and return its exit code; failures are printed as one line.

    Parameters
    ----------
    typer_app : typer.Typer
        The application (``app``; tests pass small ones).
    args : sequence of str
        The arguments after the program name.

    Returns
    -------
    int
        0 on success, else the documented exit code.
    """
    run_record.reset()
    state.reset()
    try:
        with stop_signals_as_interrupts():
            return _invoke(typer_app, args)
    except BaseException as exc:  # noqa: BLE001 - every failure becomes one line
        if isinstance(exc, BrokenPipeError) and _stdout_reader_gone():
            # The reader went away (`fgcd ... | head`): nothing left to tell it.
            _silence_stdout()
            return EXIT_OS
        failure = _classify(exc)
        if failure is None:
            raise
    _report(failure, as_json=_wants_json(args))
    return failure.code


#: The signals that stop a command as Ctrl-C does (errors.StopSignal): a supervisor's stop, a closed terminal.
STOP_SIGNALS = ("SIGTERM", "SIGHUP")


@contextmanager
def stop_signals_as_interrupts() -> Iterator[None]:
    """SIGTERM and SIGHUP raise :class:`fgcd_cli.errors.StopSignal` (a KeyboardInterrupt) for the block.

    Rule (README, "Errors"): they take the path of Ctrl-C, so the platform is
    stopped before anything else. Once one has arrived, further ones are
    ignored while the command stops (a second ``kill`` must not cut the
    platform's stop short; SIGKILL remains the supervisor's last resort). A
    signal already ignored when the command starts (``nohup``) stays ignored. The
    previous handlers come back after the block (a host process, a test
    session); off the main thread nothing is installed (Python allows it there only).
    """
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    # a signal ignored when fgcd starts stays ignored: `nohup fgcd relocate ... &` must outlive its terminal
    numbers = {
        getattr(signal, name): name
        for name in STOP_SIGNALS
        if hasattr(signal, name) and signal.getsignal(getattr(signal, name)) is not signal.SIG_IGN
    }
    received: list[int] = []

    def handler(signum, frame) -> None:  # noqa: ARG001 - the signal module's signature
        if received:
            return  # already stopping
        received.append(signum)
        raise StopSignal(signum, numbers[signum])

    previous = {num: signal.signal(num, handler) for num in numbers}
    try:
        yield
    finally:
        for num, old in previous.items():
            signal.signal(num, old)


def _stdout_reader_gone() -> bool:
    """True when stdout is a pipe whose reader has closed it (not a socket of a driver)."""
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLERR)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    except (OSError, ValueError, AttributeError):
        return False


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's final flush does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _invoke(typer_app: typer.Typer, args: Sequence[str]) -> int:
    """Parse and run the command; exceptions (including Ctrl-C) propagate unchanged.

    typer's own runner turns Ctrl-C into a silent exit 130; the click command is
    driven directly so that the interruption can be reported.
    """
    command = typer.main.get_command(typer_app)
    try:
        with command.make_context("fgcd", hoist_verbose(command, args)) as ctx:
            command.invoke(ctx)
    except typer.Exit as exc:
        return int(exc.exit_code or 0)
    except _NO_ARGS_IS_HELP as exc:
        # `fgcd` or `fgcd campaign` alone: the help is the answer, not an error.
        print(exc.format_message())
    return 0


VERBOSE_FLAGS = ("--verbose", "-v")


def hoist_verbose(command, args: Sequence[str]) -> list[str]:
    """``args`` with a ``--verbose``/``-v`` given after the subcommand moved before it, to the root's option.

    Rule: the root's ``--verbose`` works anywhere before a ``--``, except where
    the subcommand (or a group on the way) has an option of that name, or as
    the value of an option that takes one (``--site -v``): those are left alone.
    """
    args = list(args)
    end = args.index("--") if "--" in args else len(args)
    if not set(VERBOSE_FLAGS) & _flags_and_valued(command)[0]:
        return args
    cmd, i, own = command, 0, set()
    while i < end:
        token = args[i]
        flags, takes_value = _flags_and_valued(cmd)
        if token in VERBOSE_FLAGS and cmd is not command and token not in own | flags:
            args.insert(0, args.pop(i))  # the order of the others is kept: i now points at the next one
            i += 1
            continue
        if token in takes_value:
            i += 2
            continue
        sub = getattr(cmd, "commands", {}).get(token) if not token.startswith("-") else None
        if sub is not None:
            own |= flags if cmd is not command else set()
            cmd = sub
        i += 1
    return args


def _flags_and_valued(cmd) -> tuple[set[str], set[str]]:
    """``(every option name of cmd, the names of those that take a value)``."""
    names, valued = set(), set()
    for param in getattr(cmd, "params", []):
        if getattr(param, "param_type_name", "") != "option":
            continue
        opts = set(param.opts) | set(getattr(param, "secondary_opts", []))
        names |= opts
        if not (getattr(param, "is_flag", False) or getattr(param, "count", False)):
            valued |= opts
    return names, valued


def _no_args_is_help_type():
    try:
        from typer._click.exceptions import NoArgsIsHelpError
    except ImportError:  # pragma: no cover - typer releases that use click itself
        from click.exceptions import NoArgsIsHelpError
    return NoArgsIsHelpError


_NO_ARGS_IS_HELP = _no_args_is_help_type()


def _wants_json(args: Sequence[str]) -> bool:
    """True when ``--json`` is among the options (before a ``--`` separator)."""
    options = list(args)[: list(args).index("--")] if "--" in args else list(args)
    return "--json" in options


def _report(failure: Failure, *, as_json: bool) -> None:
    """Print the failure: one line on stderr; with --json also one object on stdout."""
    try:
        if as_json and not state.emitted:
            print(to_json({"error": failure.line, "code": failure.code}))
        # Plain print: one unwrapped line whatever the terminal width.
        print(failure.line, file=sys.stderr)
    except OSError:  # the terminal is gone (SIGHUP): the exit code still tells
        pass


def _classify(exc: BaseException) -> Failure | None:
    """The failure an exception means, or None for one that must propagate (a bug with --verbose)."""
    if isinstance(exc, StopSignal):
        return Failure(exc.prefix, f"{run_record.platform_clause()}; {run_record.writes_clause()}", exc.exit_code)
    if isinstance(exc, KeyboardInterrupt):
        return _interrupted()
    if isinstance(exc, FgcdError):
        return Failure("error", str(exc), exc.exit_code)
    hardware = _hardware_error_kind(exc)
    if hardware is not None:  # the platform, or the camera like it: not connected, no frame
        return Failure(f"{hardware} error", str(exc), EXIT_PLATFORM)
    if isinstance(exc, typer.Abort):
        return _aborted(exc)
    if isinstance(exc, (SystemExit, GeneratorExit)):
        return None
    # typer vendors click: usage errors carry show(), exit_code and format_message().
    if hasattr(exc, "show") and hasattr(exc, "exit_code") and hasattr(exc, "format_message"):
        return Failure("usage error", _usage_message(exc), int(exc.exit_code))
    if isinstance(exc, OSError):
        return Failure("error", os_error_line(exc), EXIT_OS)
    if is_out_of_memory(exc):
        return Failure("error", OUT_OF_MEMORY, EXIT_OS)
    if state.verbose or not isinstance(exc, Exception):
        return None
    return Failure(
        "internal error",
        f"{type(exc).__name__}: {exc} (a bug: run the same command again with --verbose and report what it prints)",
        EXIT_INTERNAL,
    )


def _hardware_error_kind(exc: BaseException) -> str | None:
    from fgcd_cli.app.platform import hardware_error_kind

    return hardware_error_kind(exc)


def _interrupted() -> Failure:
    """Ctrl-C: whether the platform was stopped and what was (not) written."""
    return Failure(
        "interrupted (Ctrl-C)", f"{run_record.platform_clause()}; {run_record.writes_clause()}", EXIT_INTERRUPTED
    )


def _aborted(exc: BaseException) -> Failure:
    """A confirmation prompt ended without an answer: Ctrl-C, no terminal, or end of input."""
    # typer.confirm turns Ctrl-C and end of input into Abort; the cause stays in __context__.
    if isinstance(exc.__context__, KeyboardInterrupt):
        return _classify(exc.__context__)
    if not stdin_is_terminal():
        return Failure("error", str(ConfirmationNeeded.for_prompt()), ConfirmationNeeded.exit_code)
    return Failure("aborted", "no answer at the confirmation prompt; nothing was done after it", EXIT_ABORTED)


def _usage_message(exc: BaseException) -> str:
    """The usage error and where to read the command's help."""
    message = exc.format_message() or "invalid command line"  # type: ignore[attr-defined]
    ctx = getattr(exc, "ctx", None)
    if ctx is not None and getattr(ctx, "command_path", None):
        return f"{message} (see '{ctx.command_path} --help')"
    return message


if __name__ == "__main__":
    main()
