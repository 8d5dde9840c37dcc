"""The ``torch4dtree`` console script: one entry point, one small module per subcommand.

Each subcommand module has ``add_arguments(parser)`` and ``run(args) -> exit code``. The modules import
nothing heavy at import time (torch, numba, OpenGL are imported inside ``run``), so building the parser
and printing ``--help`` or ``--version`` stays fast.

Exit codes: 0 success; 2 bad input (arguments, missing or malformed files and configs, an output that exists:
:class:`~torch4dtree.trees.structures.TreeError` and its subclasses, :class:`.options.UsageError`, path errors);
1 anything else: the environment stopped the command (no OpenGL, a missing optional package, a failing disk) or an
error in torch4dtree itself, which the message says is a bug to report. Errors and warnings are one line each on
stderr, prefixed with the command; ``--debug`` adds the traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import traceback
import warnings
from collections.abc import Callable, Sequence
from typing import Any, NoReturn

# (name, module, help), in the order of the pipeline
COMMANDS = (
    ("synth", "synth", "generate a dataset folder of synthetic growing plants"),
    ("info", "info", "summarise a tree file, a sequence folder or a dataset folder"),
    ("register", "register", "register two trees (SWC or .mat): distances, correspondence, geodesic"),
    ("register4d", "register4d", "register two 4D trees (sequence folders) in space and time"),
    ("fit", "fit", "fit the generative model of 4D trees on a dataset folder (writes a run directory)"),
    ("sample", "sample", "generate 4D trees from a fitted model: sequence folders and videos"),
    ("forecast", "forecast", "complete a partly observed 4D tree with a fitted model"),
    ("render", "render", "render a tree file, sequence or dataset folder to PNG / GIF / MP4"),
    ("evaluate", "evaluate", "the paper's experiments and the generative model's quality on a data folder (report)"),
    ("benchmark", "benchmark", "time the registration engine"),
    ("warmup", "warmup", "compile the registration kernels now (once per install), so later commands start fast"),
)

DESCRIPTION = ("Statistical analysis and generation of 4D tree-shaped structures: growing plants as sequences "
               "of 3D branching skeletons.")
EPILOG = ("Run 'torch4dtree COMMAND --help' for the options of a command. Exit codes: 0 success, 2 bad input, "
          "1 other failures.")

# bad paths: missing, existing or of the wrong kind (OSErrors, but the user's input)
BAD_PATH = (FileExistsError, FileNotFoundError, IsADirectoryError, NotADirectoryError)
# the package's input errors, by module and class name: looked up in sys.modules when an error is caught, so that
# building the parser imports no torch (a module that raised one of them is loaded by then)
INPUT_ERRORS = (("torch4dtree.trees.structures", "TreeError"), ("torch4dtree.space.karcher", "SlotLimitError"))
# the environment stopped the command: a missing optional package, a failing disk (or an error caused by one, as
# the renderer's "no OpenGL")
ENVIRONMENT = (ImportError, OSError)
DEBUG_HELP = "on an error, print the traceback too (give it with a bug report)"
BUG_NOTE = "this is a bug in torch4dtree; please report it with --debug output"


class _Parser(argparse.ArgumentParser):
    """Argument errors as one line (not the usage block), exit code 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser: every subcommand with its arguments, or with ``only`` just that one's arguments (the others
    are listed but not imported: what ``main`` does, so ``torch4dtree --help`` imports no subcommand)."""
    from .. import __version__

    parser = _Parser(prog="torch4dtree", description=DESCRIPTION, epilog=EPILOG)
    parser.add_argument("--version", action="version", version=f"torch4dtree {__version__}")
    parser.add_argument("--debug", action="store_true", help=DEBUG_HELP)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", title="commands")
    for name, module, help_ in COMMANDS:
        p = sub.add_parser(name, help=help_, description=help_[0].upper() + help_[1:] + ".")
        # also after the command; SUPPRESS keeps a --debug given before it
        p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=DEBUG_HELP)
        if only is None or only == name:
            mod = importlib.import_module(f".{module}", __package__)
            mod.add_arguments(p)
            p.set_defaults(func=mod.run)
    return parser


def _message(err: BaseException) -> str:
    """One line for an exception: OS errors as ``path: reason`` rather than ``[Errno 2] ...: 'path'``."""
    if isinstance(err, OSError) and err.strerror and err.filename is not None:
        return f"{err.filename}: {err.strerror}"
    if isinstance(err, ModuleNotFoundError) and not str(err):
        return f"missing package {err.name}"
    text = str(err) or type(err).__name__
    return " ".join(text.split())  # one line


def exit_code(err: BaseException) -> int:
    """2 for bad input (module doc), 1 for anything else.

    Example:
        >>> from torch4dtree.cli.options import UsageError
        >>> exit_code(UsageError("--n must be at least 1")), exit_code(FileNotFoundError("x.swc"))
        (2, 2)
        >>> exit_code(ValueError("an internal check failed")), exit_code(ModuleNotFoundError("pyrender"))
        (1, 1)
    """
    from .options import UsageError

    if isinstance(err, (UsageError, *BAD_PATH)):
        return 2
    for module, name in INPUT_ERRORS:
        cls = getattr(sys.modules.get(module), name, None)
        if cls is not None and isinstance(err, cls):
            return 2
    return 1


def is_environment_error(err: BaseException) -> bool:
    """Whether ``err`` (not bad input) comes from the environment rather than from torch4dtree: a missing
    package, a failing disk, or an error raised from one of those (``raise ... from``)."""
    return isinstance(err, ENVIRONMENT) or isinstance(err.__cause__, ENVIRONMENT)


def _warning_printer(prefix: str) -> Callable[..., None]:
    """``warnings.showwarning`` replacement: ``prefix: warning: message``, without the Python source line."""

    def show(message: Warning | str, category: type[Warning], filename: str, lineno: int, file: Any = None,
             line: str | None = None) -> None:
        print(f"{prefix}: warning: {' '.join(str(message).split())}", file=sys.stderr if file is None else file)

    return show


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (the console script exits with it)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    names = [name for name, _, _ in COMMANDS]
    command = next((a for a in argv if not a.startswith("-")), "")  # the top level has no option with a value
    parser = build_parser(only=command if command in names else "")
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help / --version (0) or an argument error (2), already printed
        return e.code if isinstance(e.code, int) else 0
    prefix = f"torch4dtree {args.command}"
    with warnings.catch_warnings():
        warnings.showwarning = _warning_printer(prefix)
        try:
            return int(args.func(args) or 0)
        except KeyboardInterrupt:
            print(f"{prefix}: interrupted", file=sys.stderr)
            return 130
        except Exception as e:  # noqa: BLE001 - every error becomes one line and an exit code
            code = exit_code(e)
            if args.debug:
                traceback.print_exc()
            bug = code == 1 and not is_environment_error(e)
            print(f"{prefix}: error: {_message(e)}" + (f" ({BUG_NOTE})" if bug else ""), file=sys.stderr)
            return code


if __name__ == "__main__":
    sys.exit(main())
