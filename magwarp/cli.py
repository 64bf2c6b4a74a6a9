"""The ``magwarp`` command: ``magwarp <subcommand> [options]``.

Subcommand modules live in :mod:`magwarp.commands` and are imported only when chosen, so ``magwarp --help`` is
fast. User mistakes are reported as one line on stderr with exit code 2 (``--debug`` shows the traceback).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import pkgutil
import sys

from magwarp.commands import SUBCOMMANDS, CommandError, UsageError

EXIT_USAGE = 2
EXIT_MISSING = 2

EPILOG = """examples:
  magwarp render --synthetic --layout B1 --worlds 4 --steps 60 -o run.gif
  magwarp view --synthetic --viewer usd -o run.usda
  magwarp <subcommand> --help
"""


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (argparse prints the whole usage block by default)."""

    def error(self, message):
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def available_subcommands() -> dict[str, str]:
    """Known subcommands plus any other module found in magwarp/commands, with their one-line help."""
    names = dict(SUBCOMMANDS)
    import magwarp.commands as pkg

    for mod in pkgutil.iter_modules(pkg.__path__):
        if not mod.name.startswith("_") and mod.name not in names:
            names[mod.name] = f"(see 'magwarp {mod.name} --help')"
    return names


def _module_exists(name: str) -> bool:
    return importlib.util.find_spec(f"magwarp.commands.{name}") is not None


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("magwarp")
    except Exception:  # noqa: BLE001 - not installed as a distribution (e.g. run from a checkout)
        return "0+unknown"


def build_parser(selected: str | None = None) -> argparse.ArgumentParser:
    """The top-level parser; only ``selected``'s module is imported to add its real options."""
    parser = _Parser(prog="magwarp", description="magwarp: batched magnetic levitation simulator and RL envs on Warp.",
                     epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"magwarp {_version()}")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="SUBCOMMAND", parser_class=_Parser)
    parser.selected_parser = None
    for name, help_line in available_subcommands().items():
        if name == selected:
            module = importlib.import_module(f"magwarp.commands.{name}")
            p = module.add_parser(sub)
            p.set_defaults(_run=module.run)
            parser.selected_parser = p
        else:
            present = _module_exists(name)
            sub.add_parser(name, help=help_line if present else f"{help_line} [not installed]", add_help=False)
    return parser


def _selected(argv: list[str]) -> str | None:
    for token in argv:
        if token == "--":
            return None
        if not token.startswith("-"):
            return token
    return None


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    name = _selected(argv)
    debug = "--debug" in argv
    if name is not None and name not in available_subcommands():
        sys.stderr.write(f"magwarp: error: unknown subcommand {name!r}; choose one of "
                         f"{', '.join(available_subcommands())} (see 'magwarp --help')\n")
        return EXIT_USAGE
    if name is not None and not _module_exists(name):
        sys.stderr.write(f"magwarp: the '{name}' subcommand is not available in this version "
                         f"(magwarp/commands/{name}.py is missing)\n")
        return EXIT_MISSING
    try:
        parser = build_parser(name)
        args, extra = parser.parse_known_args(argv)
        if extra:
            (parser.selected_parser or parser).error(f"unrecognized arguments: {' '.join(extra)}")
    except SystemExit as e:  # --help, --version and argparse errors
        return int(e.code or 0) if isinstance(e.code, int) or e.code is None else EXIT_USAGE
    if args.command is None:
        parser.print_help()
        return 0
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        sys.stderr.write("magwarp: interrupted\n")
        return 130
    except (UsageError, ValueError, FileNotFoundError, PermissionError, IsADirectoryError) as e:
        if debug:
            raise
        from magwarp.layout import LayoutError

        plain = isinstance(e, (UsageError, LayoutError))
        kind, hint = ("", "") if plain else (f"{type(e).__name__}: ", " (--debug for the traceback)")
        sys.stderr.write(f"magwarp {args.command}: error: {kind}{e}{hint}\n")
        return EXIT_USAGE
    except (ImportError, CommandError) as e:  # a missing optional dependency or machine feature, in one line
        if debug:
            raise
        sys.stderr.write(f"magwarp {args.command}: error: {e}\n")
        return 1


if __name__ == "__main__":
    sys.exit(main())
