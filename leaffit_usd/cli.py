"""The ``leaffit-usd`` command.

Each subcommand lives in its own module under ``leaffit_usd/commands/`` and exposes
``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``; they are discovered here,
so adding a command touches no other file.

Exit codes: 0 success; 2 bad input or usage (one line on stderr, no traceback); 1 internal error.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import os
import pkgutil
import re
import sys

import leaffit_usd.lazy_imports as lazy_imports
from leaffit_usd.version import __version__
from leaffit_usd.errors import UserError

log = logging.getLogger("leaffit_usd")


# A value that starts with '-' but is not an option: a negative number or a list of numbers
# ("-1.87,1.50,2.05", "-1e-3") or a signed axis ("-y"). argparse only takes plain negative numbers
# ("-1", "-0.5") as values; anything else that starts with '-' it reads as an unknown option and
# then refuses "--root -1.87,1.50,2.05" with "expected one argument".
_NUM = r"(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_DASH_VALUE = re.compile(rf"-(?:{_NUM}(?:\s*,\s*[+-]?{_NUM})*|[xyzXYZ])")


def join_dash_values(parser: argparse.ArgumentParser, args: list[str]) -> list[str]:
    """``args`` with every ``--opt VALUE`` whose VALUE looks like a negative number, a list of
    numbers starting with a negative one, or a signed axis rewritten as ``--opt=VALUE``.

    Only options of ``parser`` that take exactly one value are joined (a flag, or a token that is
    itself one of the parser's options, is left alone), unique abbreviations included (``--u -y``);
    nothing after ``--`` is touched. This is how every command accepts ``--root -1.87,1.50,2.05``
    and ``--up -y`` (the ``=`` form keeps working).
    """
    table = getattr(parser, "_option_string_actions", {})  # argparse's option-string -> action map
    out, i = [], 0
    while i < len(args):
        tok = args[i]
        if tok == "--":
            out.extend(args[i:])
            break
        if (i + 1 < len(args) and tok.startswith("-") and "=" not in tok
                and _DASH_VALUE.fullmatch(args[i + 1]) and args[i + 1] not in table):
            action = table.get(tok)
            if action is None and tok.startswith("--"):
                hits = {table[s] for s in table if s.startswith(tok) and s.startswith("--")}
                action = hits.pop() if len(hits) == 1 else None
            if action is not None and action.option_strings and action.nargs is None:
                out.append(f"{tok}={args[i + 1]}")
                i += 2
                continue
        out.append(tok)
        i += 1
    return out


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors as one line and exit code 2."""

    def parse_known_args(self, args=None, namespace=None):
        args = sys.argv[1:] if args is None else list(args)
        return super().parse_known_args(join_dash_values(self, args), namespace)

    def error(self, message):  # noqa: D401 - argparse API
        sys.stderr.write(f"{self.prog}: error: {message} (see --help)\n")
        raise SystemExit(2)


def _commands(only: str | None = None):
    """The command modules, in ``ORDER``; only the one named ``only`` when it is a command (a
    run of one command imports only its own module: the others pull in USD, meshing and the
    editor, about a second of start-up that ``segment`` does not need)."""
    import leaffit_usd.commands as pkg

    names = [i.name for i in pkgutil.iter_modules(pkg.__path__) if not i.name.startswith("_")]
    if only in names:
        names = [only]
    mods = [importlib.import_module(f"{pkg.__name__}.{n}") for n in sorted(names)]
    return sorted(mods, key=lambda m: getattr(m, "ORDER", 50))


def _command_word(argv: list) -> str | None:
    """The command named in ``argv`` (its first word when that is not an option), else None."""
    return argv[0] if argv and not argv[0].startswith("-") else None


def build_parser(argv=None) -> argparse.ArgumentParser:
    """The argument parser: every command, or with ``argv`` naming one, just that command (the
    top-level ``--help`` and an unknown command still list them all)."""
    parser = _Parser(
        prog="leaffit-usd",
        description="Turn a 3D Gaussian Splatting capture of a plant into a compact, editable "
                    "USD asset: one template leaf mesh, per-leaf MLS control points, a stem.",
        epilog="Typical use:  leaffit-usd convert plant.ply -o plant.usda\n"
               "Run 'leaffit-usd COMMAND --help' for a command's options.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"leaffit-usd {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for mod in _commands(None if argv is None else _command_word(list(argv))):
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        p.add_argument("-q", "--quiet", action="store_true", help="print only warnings and errors")
        p.add_argument("--debug", action="store_true", help="show tracebacks for internal errors")
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


class _OneLine(logging.Formatter):
    def format(self, record):
        msg = record.getMessage()
        return msg if record.levelno < logging.WARNING else f"{record.levelname.lower()}: {msg}"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    lazy_imports.defer()  # library modules no command uses load only if something asks for them
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_OneLine())
    log.handlers[:] = [handler]
    log.setLevel(logging.WARNING if args.quiet else logging.INFO)
    log.propagate = False
    debug = args.debug or os.environ.get("LEAFFIT_DEBUG") == "1"
    try:
        return int(args._run(args) or 0)
    except UserError as e:
        sys.stderr.write(f"leaffit-usd {args.command}: error: {e}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("leaffit-usd: interrupted\n")
        return 130
    except Exception as e:  # internal error: one line unless --debug
        if debug:
            raise
        sys.stderr.write(f"leaffit-usd {args.command}: internal error: {type(e).__name__}: {e} "
                         f"(rerun with --debug for a traceback)\n")
        return 1


if __name__ == "__main__":
    sys.exit(main())
