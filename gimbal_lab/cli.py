"""Command line: ``gimbal-lab run STUDY`` runs a study and writes its tables and figures.

``gimbal-lab reproduce`` is ``gimbal-lab run paper``. Other commands register themselves here
through an ``add_parsers(subparsers)`` function of their module, so a new command is a module,
not a branch in this file.
"""

from __future__ import annotations

import argparse
import os
import sys

# This process runs studies itself when asked for one job; numpy's BLAS must be limited before
# numpy is imported (see gimbal_lab.runner.CHILD_THREAD_LIMITS). A value already set is kept.
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

#: Modules that add sub-commands; each has ``add_parsers(subparsers)`` and sets ``func``.
_COMMAND_MODULES = ("gimbal_lab.studies.cli", "gimbal_lab.realworld", "gimbal_lab.show", "gimbal_lab.mavlink.cli")


def build_parser() -> argparse.ArgumentParser:
    from importlib import import_module

    from . import __version__

    parser = argparse.ArgumentParser(
        prog="gimbal-lab",
        description="gimbal-lab: active (gimbal) vs passive visual tracking from drones, after Hansen & "
                    "de Figueiredo, Drones 2024 (doi:10.3390/drones8020055).",
        epilog="Start with: gimbal-lab run paper --out results   (gimbal-lab COMMAND --help for a command's options)")
    parser.add_argument("--version", action="version", version=f"gimbal-lab {__version__}")
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


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    # a command module may set ``_parser`` to its sub-parser so its errors name the sub-command
    return int(args.func(args, getattr(args, "_parser", None) or parser) or 0)


if __name__ == "__main__":
    sys.exit(main())
