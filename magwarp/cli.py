"""The ``magwarp`` command: ``magwarp <subcommand> [options]``.

Subcommand modules live in :mod:`magwarp.commands` and are imported only when chosen, so ``magwarp --help`` is
fast. Every error ends the command with one line on stderr and a non-zero exit code, never a traceback
(``--debug`` shows it): user mistakes exit with 2, problems of the machine or of a policy's own code with 1.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import pkgutil
import sys
import warnings

from magwarp.commands import SUBCOMMANDS, CommandError, UsageError

EXIT_USAGE = 2
EXIT_MISSING = 2
EXIT_FAILURE = 1
#: longest error line printed (a policy's exception can carry a whole tensor dump)
MAX_LINE = 600

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
    previous = warnings.formatwarning
    if not debug:
        warnings.formatwarning = _one_line_warning
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        sys.stderr.write("magwarp: interrupted\n")
        return 130
    except Exception as e:  # noqa: BLE001 - every error is reported as one line (--debug: the traceback)
        if debug:
            raise
        code, line = error_line(e)
        sys.stderr.write(f"magwarp {args.command}: error: {line}\n")
        return code
    finally:
        warnings.formatwarning = previous


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    return f"magwarp: {category.__name__}: {_flat(str(message))}\n"


def _flat(text: str) -> str:
    text = " ".join(text.split())
    return text if len(text) <= MAX_LINE else text[:MAX_LINE - 3] + "..."


def error_line(e: BaseException) -> tuple[int, str]:
    """Exit code and one-line message for an error: a user mistake (exit 2, the message alone for ours and
    ``TypeName: message`` for others), a missing optional package or machine feature (exit 1), or anything else,
    e.g. a full disk or a policy's own exception (exit 1, ``TypeName: message``)."""
    from magwarp.layout import LayoutError

    hint = " (--debug for the traceback)"
    if isinstance(e, (UsageError, LayoutError)):
        return EXIT_USAGE, _flat(str(e))
    if isinstance(e, (ValueError, FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError)):
        return EXIT_USAGE, f"{type(e).__name__}: {_flat(str(e))}{hint}"
    if isinstance(e, (ImportError, CommandError)):
        return EXIT_FAILURE, _flat(str(e))
    return EXIT_FAILURE, f"{type(e).__name__}: {_flat(str(e)) or 'no message'}{hint}"


if __name__ == "__main__":
    sys.exit(main())
