"""The ``torch4dtree`` console script: one entry point, one small module per subcommand.

Each subcommand module has ``add_arguments(parser)`` and ``run(args) -> exit code``. The modules import
nothing heavy at import time (torch, numba, OpenGL are imported inside ``run``), so building the parser
and printing ``--help`` or ``--version`` stays fast.

Exit codes: 0 success, 2 bad input (arguments, missing or malformed files, an output that exists),
1 anything else that stops a command (no OpenGL, a missing optional package, a failing disk).
Errors and warnings are one line each on stderr, prefixed with the command.
"""

from __future__ import annotations

import argparse
import importlib
import sys
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

# bad input: wrong arguments, missing / malformed / existing files (TreeError and UsageError are ValueErrors)
BAD_INPUT = (ValueError, FileExistsError, FileNotFoundError, IsADirectoryError, NotADirectoryError)
# the environment stopped the command: no OpenGL, a missing optional package, a failing disk
FAILURE = (RuntimeError, ImportError, OSError)


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
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", title="commands")
    for name, module, help_ in COMMANDS:
        p = sub.add_parser(name, help=help_, description=help_[0].upper() + help_[1:] + ".")
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
        except BAD_INPUT as e:
            print(f"{prefix}: error: {_message(e)}", file=sys.stderr)
            return 2
        except FAILURE as e:
            print(f"{prefix}: error: {_message(e)}", file=sys.stderr)
            return 1
        except KeyboardInterrupt:
            print(f"{prefix}: interrupted", file=sys.stderr)
            return 130


if __name__ == "__main__":
    sys.exit(main())
