"""The ``shipstar`` command line.

Each sub-command lives in its own module ``shipstar/cli/_cmd_<name>.py`` that defines

``register(subparsers) -> argparse.ArgumentParser``
    add the sub-command's parser (with an example in its epilog) and
    ``parser.set_defaults(run=<function(args) -> int>)``.

Modules import their heavy dependencies inside ``run`` so that ``shipstar --help`` is
fast.  Errors a user can cause are :class:`shipstar.errors.ShipstarError`; they are
printed as one line ``shipstar <command>: error: <message>`` with exit code 2, never a
traceback (``--debug`` shows it).

Warnings raised while a command runs (:class:`shipstar.errors.AccuracyWarning`:
extrapolated Earth orientation, an expired leap-second table, a refraction model that
differs from the dock calibration's) are recorded and printed once each, as one line
``shipstar <command>: warning: <message>`` on stderr after the command's output; a
command can put them into its own output too (``shipstar.cli._common.accuracy_warnings``).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings

from shipstar.errors import AccuracyWarning, ShipstarError

__all__ = ["main", "build_parser", "OneLineErrorParser"]

EXIT_OK = 0
EXIT_FAILED = 1      # the job ran but did not succeed (e.g. a frame did not solve)
EXIT_BAD_INPUT = 2   # bad input: one-line message on stderr


def _command_modules(only=None):
    """The command modules; with ``only`` (a command word such as ``solve``) just the
    module ``_cmd_<only>`` if there is one (``shipstar solve`` then imports no other
    command's dependencies; the parser is rebuilt in full if it does not register it)."""
    import shipstar.cli as pkg

    if only is not None:
        mine = "_cmd_" + only.replace("-", "_")
        if not mine.isidentifier():
            return []
        try:
            return [importlib.import_module(f"shipstar.cli.{mine}")]
        except ModuleNotFoundError as exc:
            if exc.name != f"shipstar.cli.{mine}":
                raise
            return []
    import pkgutil

    names = sorted(m.name for m in pkgutil.iter_modules(pkg.__path__) if m.name.startswith("_cmd_"))
    return [importlib.import_module(f"shipstar.cli.{n}") for n in names]


class OneLineErrorParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line on stderr, exit code 2.

    Sub-parsers made with ``add_subparsers`` inherit the class, so every command and
    sub-command behaves the same way.

    Options are never guessed from a prefix (``allow_abbrev=False``: ``measure --ins FILE``
    is an unrecognized argument, not ``--install``), and a negative angle in degrees,
    minutes and seconds (``--lat-deg -33d51m``) is a value, as a negative number is.
    """

    def __init__(self, *args, **kwargs):
        import re

        kwargs["allow_abbrev"] = False
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"^-\d+$|^-\d*\.\d+$|^-\d+(?:\.\d*)?(?:[eE][-+]?\d+)?$"
                                                   r"|^-\d+\s*[dD°:]")

    def error(self, message: str):  # noqa: D102 - argparse API
        print(f"{self.prog}: error: {message} (see '{self.prog} --help')", file=sys.stderr)
        raise SystemExit(EXIT_BAD_INPUT)


def build_parser(command=None) -> argparse.ArgumentParser:
    from shipstar import __version__

    parser = OneLineErrorParser(
        prog="shipstar",
        description="Ship heading, pitch and roll to arcseconds from star sensor images.",
        epilog="Run 'shipstar COMMAND --help' for a command's options and an example.",
    )
    parser.add_argument("--version", action="version", version=f"shipstar {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    mods = _command_modules(command) if command else []
    for mod in mods:
        mod.register(sub)
    if command and command in sub.choices:
        return parser
    if mods:
        return build_parser()
    for mod in _command_modules():
        mod.register(sub)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``shipstar`` console command; returns the exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv  # accepted anywhere on the line, not only before the command
    argv = [a for a in argv if a != "--debug"]
    first = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(first if argv and argv[0] == first else None)
    args, extra = parser.parse_known_args(argv)
    args.debug = debug
    if extra:
        where = f"shipstar {args.command}" if getattr(args, "command", None) else "shipstar"
        print(f"{where}: error: unrecognized arguments: {' '.join(extra)} (see '{where} --help')",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    if not getattr(args, "run", None):
        parser.print_help()
        return EXIT_BAD_INPUT
    where = _command_name(args)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", AccuracyWarning)
        args.caught_warnings = caught
        eop_before = _eop_env()
        try:
            if getattr(args, "eop", None):          # --eop FILE: every command that has it
                from shipstar.cli._model_inputs import apply_eop

                apply_eop(args)
            code = int(args.run(args) or 0)
        except ShipstarError as exc:
            if args.debug:
                raise
            print(f"{where}: error: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
        except (OSError, MemoryError) as exc:
            if args.debug:
                raise
            from shipstar.cli._oserror import os_error_message

            print(f"{where}: error: {os_error_message(exc, args)}", file=sys.stderr)
            return EXIT_BAD_INPUT
        except KeyboardInterrupt:
            print(f"{where}: interrupted", file=sys.stderr)
            return 130
        finally:
            _eop_env(eop_before)                      # an in-process call leaves no --eop behind
    _print_warnings(where, caught)
    return code


def _eop_env(value=False):
    """The ``--eop`` table in force for this process (no argument), or put ``value`` back."""
    import os

    name = "SHIPSTAR_EOP_FILE"
    if value is False:
        return os.environ.get(name)
    if value is None:
        os.environ.pop(name, None)
    else:
        os.environ[name] = value


def _command_name(args) -> str:
    """``shipstar measure``, ``shipstar calibrate install``, ..."""
    words = [args.command] + [v for k, v in sorted(vars(args).items())
                              if k.endswith("_command") and isinstance(v, str)]
    return " ".join(["shipstar", *words])


def _print_warnings(where: str, caught) -> None:
    """Each distinct warning once, on one line (the category named unless it is an
    AccuracyWarning)."""
    lines = []
    for w in caught:
        text = " ".join(str(w.message).split())
        if not issubclass(w.category, AccuracyWarning):
            text = f"{w.category.__name__}: {text}"
        lines.append(f"{where}: warning: {text}")
    for line in dict.fromkeys(lines):
        print(line, file=sys.stderr)


def _entry() -> None:  # pragma: no cover - console script wrapper
    code = main()
    # Every output is written and closed by now.  Skip the interpreter's last garbage
    # collection, a walk over every object the command loaded (NumPy, Dask, the catalog...)
    # for reference cycles that the process's end releases anyway: 0.17-0.18 s at the end
    # of `measure-archive` against 0.04 s without it (docs/archive.md *Speed*).  The exit
    # still runs the atexit handlers, flushes the standard streams and releases the
    # modules' objects.
    import gc

    gc.freeze()
    sys.exit(code)
