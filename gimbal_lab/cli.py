"""Command line: ``gimbal-lab run STUDY`` runs a study and writes its tables and figures.

``gimbal-lab reproduce`` is ``gimbal-lab run paper``. Other commands register themselves here
through an ``add_parsers(subparsers)`` function of their module, so a new command is a module,
not a branch in this file. Those modules import nothing heavy (numpy, OpenCV, the renderer,
pandas, pymavlink) until their command runs, so ``gimbal-lab --help`` and every ``COMMAND --help``
answer at once.

Errors reach the user as one line on stderr, naming the culprit: a bad argument or output path
exits 2, a failure while working exits 1, Ctrl-C exits 130 saying what is kept. SIGTERM (``kill``,
a job scheduler's time limit) stops a command as Ctrl-C does, says the same, and exits 143.
``--debug`` shows the traceback of an error instead.
"""

from __future__ import annotations

import os
import sys


def _interrupted_at_start(signum, frame):
    """Ctrl-C while the command line starts or ends (imports, parsing, exit): one line and exit 130,
    never a traceback. The process ends here (``os._exit``, after flushing what was printed): an
    exception raised from a handler can land where Python ignores it (a weak reference's callback
    inside the import system), and the Ctrl-C would be lost. Nothing is being written yet (or any
    more) at these moments."""
    for stream, text in ((sys.stdout, ""), (sys.stderr, "\ngimbal-lab: interrupted\n")):
        try:
            stream.write(text)
            stream.flush()
        except Exception:  # noqa: BLE001 - a closed stream: the exit status says it
            pass
    os._exit(130)


def _launched() -> bool:
    """Is this process the ``gimbal-lab`` command (its console script, or ``python -m gimbal_lab.cli``),
    rather than a program or test that imports this module?"""
    main = sys.modules.get("__main__")
    return os.path.basename(getattr(main, "__file__", None) or "") in ("gimbal-lab", "cli.py")


# First of all, before any import that runs Python code (``signal`` and ``threading`` build classes
# and enums: a Ctrl-C amid them was a traceback): from here until the command itself runs, Ctrl-C
# is one line. The interpreter's own start-up, before this module is imported, is beyond reach.
if _launched():
    import _signal  # the C module beneath ``signal``: nothing of Python's runs before the handler

    try:
        _signal.signal(_signal.SIGINT, _interrupted_at_start)
    except ValueError:  # not the main thread: its caller's handling stands
        pass

import argparse  # noqa: E402
import contextlib  # noqa: E402
import signal  # noqa: E402
import threading  # noqa: E402

from .argtypes import length_m, nonnegative_int, positive_int  # noqa: F401 (the commands' types, kept here too)
from . import interrupts  # noqa: E402

# This process runs studies itself when asked for one job; numpy's BLAS must be limited before
# numpy is imported (see gimbal_lab.runner.CHILD_THREAD_LIMITS). A value already set is kept.
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

#: Modules that add sub-commands; each has ``add_parsers(subparsers)`` and sets ``func``.
_COMMAND_MODULES = ("gimbal_lab.studies.cli", "gimbal_lab.realworld_cli", "gimbal_lab.show_cli",
                    "gimbal_lab.mavlink.cli")

EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 1, 2, 130
#: Exit status after SIGTERM: 128 + the signal's number, as a shell reports a process it ended.
EXIT_TERMINATED = 128 + signal.SIGTERM



class Terminated(KeyboardInterrupt):
    """SIGTERM reached the command: raised where Ctrl-C's KeyboardInterrupt would be, so a sweep
    stops its workers and keeps its finished runs exactly as after Ctrl-C."""


@contextlib.contextmanager
def _sigterm_stops_like_ctrl_c(received: list):
    """While the block runs, SIGTERM raises :class:`Terminated` (and is noted in ``received``);
    the previous handler is restored after. Only the main thread can handle signals: elsewhere
    (a command called from a thread) SIGTERM keeps its own disposition."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        received.append(signum)
        raise Terminated("terminated")

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser, reporting a bad argument in one line on stderr (exit 2), without the
    usage block: ``gimbal-lab run: error: --jobs: must be an integer >= 1, got '0'``."""

    def error(self, message: str):
        own = message.startswith(("argument ", "the following arguments", "unrecognized arguments"))
        hint = f" (see {self.prog} --help)" if own else ""  # argparse's own messages name no remedy
        self.exit(EXIT_USAGE, f"{self.prog}: error: {' '.join(message.split())}{hint}\n")


class _Version(argparse.Action):
    """``--version``: reads the installed version only when asked (importlib.metadata is slow)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        from . import __version__

        parser.exit(0, f"gimbal-lab {__version__}\n")


def build_parser() -> argparse.ArgumentParser:
    from importlib import import_module

    parser = ArgumentParser(
        prog="gimbal-lab",
        description="gimbal-lab: active (gimbal) vs passive visual tracking from drones, after Hansen & "
                    "de Figueiredo, Drones 2024 (doi:10.3390/drones8020055).",
        epilog="Start with: gimbal-lab run paper --out results   (gimbal-lab COMMAND --help for a command's options)")
    parser.add_argument("--version", action=_Version, help="print the version and exit")
    parser.add_argument("--debug", action="store_true",
                        help="show the traceback of an error (by default an error is one line)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _COMMAND_MODULES:
        try:
            module = import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
            continue
        module.add_parsers(sub)
    return parser


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text


def _known(exc: BaseException) -> tuple[int, str] | None:
    """The exit status and message of an error the lab reports itself, or None for any other."""
    outputs = sys.modules.get("gimbal_lab.outputs")
    runner = sys.modules.get("gimbal_lab.runner")
    if outputs is not None and isinstance(exc, outputs.OutputError):
        return EXIT_USAGE, _one_line(exc)
    if outputs is not None and isinstance(exc, outputs.ReportNotWritten):  # it says what state the folder is in
        return EXIT_FAILED, _one_line(exc)
    if runner is not None and isinstance(exc, (runner.StoreError, runner.SweepFailed)):
        return EXIT_FAILED, _one_line(exc)
    if isinstance(exc, MemoryError):
        return EXIT_FAILED, "out of memory (a smaller input, or fewer --jobs, may fit)"
    return None


def _raised_by_ctrl_c(exc: BaseException) -> bool:
    """Was ``exc`` raised while handling (or from) a KeyboardInterrupt, anywhere down its chain?"""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def _warn_in_one_line(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"gimbal-lab: warning: {' '.join(str(message).split())}", file=sys.stderr if file is None else file)


def main(argv=None) -> int:
    launched = signal.getsignal(signal.SIGINT) is _interrupted_at_start
    try:
        return _main(argv, launched)
    finally:
        if launched:  # a Ctrl-C as the interpreter exits is one line too
            signal.signal(signal.SIGINT, _interrupted_at_start)


class _CtrlC:
    """The command's SIGINT handler: KeyboardInterrupt, as Python's own, and a note that it came
    (a library may turn the KeyboardInterrupt into another error: numpy, amid its C extensions'
    import, raises an ImportError that no longer names it)."""

    def __init__(self):
        interrupts.clear()

    @property
    def received(self) -> bool:
        return interrupts.received()

    def __call__(self, signum, frame):
        interrupts.note_interrupt()  # commands stop on it after imports that may swallow the exception
        raise KeyboardInterrupt


def _main(argv, launched: bool) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help()
        return EXIT_USAGE
    ctrl_c = _CtrlC()
    if launched:  # the command's own handling of Ctrl-C (what is kept, exit 130) takes over
        signal.signal(signal.SIGINT, ctrl_c)
    # a command module sets ``_parser`` to its sub-parser so its errors name the sub-command
    command = getattr(args, "_parser", None) or parser
    terminated: list = []  # SIGTERM's number once it arrived
    if args.debug:
        with _sigterm_stops_like_ctrl_c(terminated):
            return int(args.func(args, command) or 0)
    import warnings

    show = warnings.showwarning
    warnings.showwarning = _warn_in_one_line
    try:
        with _sigterm_stops_like_ctrl_c(terminated):
            status = int(args.func(args, command) or 0)
        if ctrl_c.received and status == 0:
            # a library swallowed the KeyboardInterrupt (trimesh's optional imports catch every
            # exception): the command ran on, but a Ctrl-C came, and success is not what to report
            raise KeyboardInterrupt
        return status
    except KeyboardInterrupt as exc:
        # RunInterrupted and the report's interruption say what is kept; a bare Ctrl-C, that it stopped
        said = _one_line(exc) if str(exc) and not isinstance(exc, Terminated) else "interrupted"
        print(f"\n{command.prog}: {'SIGTERM: ' if terminated else ''}{said}", file=sys.stderr)
        return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED
    except Exception as exc:  # noqa: BLE001 - every error is one line unless --debug
        if ctrl_c.received or _raised_by_ctrl_c(exc):  # e.g. numpy turns a Ctrl-C amid its import into an ImportError
            print(f"\n{command.prog}: {'SIGTERM: ' if terminated else ''}interrupted", file=sys.stderr)
            return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED
        known = _known(exc)
        if known is None:
            status, message = EXIT_FAILED, (f"{type(exc).__name__}: {_one_line(exc)} (an unexpected error: run "
                                             "again with gimbal-lab --debug ... for the traceback)")
        else:
            status, message = known
        print(f"{command.prog}: error: {message}", file=sys.stderr)
        return status
    finally:
        warnings.showwarning = show


if __name__ == "__main__":
    sys.exit(main())
