"""The command-line conventions of the scripts in this folder, the same as the package's commands.

* A folder of results is ``--output-dir`` / ``-o`` (as ``lnn-torch evaluate`` and ``identify``); a
  single file is ``--output`` / ``-o`` (as ``lnn-torch generate``, ``simulate`` and ``import``). An old
  spelling keeps working, hidden from the help, with one line on stderr saying what to use instead.
* A script ends by printing every path it wrote, on one line: ``wrote PATH, PATH, ...``.
* The help states each default once: where the option's help does not already say it, and never for
  an option without one (None, False, an empty string).

Not a script: the others import it (``python scripts/X.py`` puts this folder on ``sys.path``); the
benchmarks (``benchmarks/``) use the same module through ``benchmarks/timing.py``.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _shown(default) -> str:
    """A default as one would type it: lists space-separated, paths in the project from its root."""
    if isinstance(default, (list, tuple)):
        return " ".join(str(x) for x in default)
    if isinstance(default, (str, Path)) and os.path.isabs(default):
        rel = os.path.relpath(default, ROOT)
        if not rel.startswith(os.path.join("..", "..")):
            return f"<project>/{rel}"
    return str(default)


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """The description as written; each option's default once (added where its help does not say it)."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if ("default" in text or default is None or default is False or default is argparse.SUPPRESS
                or (isinstance(default, (str, list, tuple)) and not default)
                or not (action.option_strings or action.nargs in (argparse.OPTIONAL, argparse.ZERO_OR_MORE))):
            return text
        shown = _shown(default).replace("%", "%%")
        return f"{text} (default: {shown})" if text else f"default: {shown}"


class _DeprecatedAlias(argparse.Action):
    """An old spelling of an option: stores into the new option's destination, with one line on stderr."""

    def __init__(self, option_strings, dest, new: str, **kwargs):
        self.new = new
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog}: {option_string} is deprecated; use {self.new}", file=sys.stderr)
        setattr(namespace, self.dest, values)


def _aliases(ap: argparse.ArgumentParser, dest: str, new: str, old) -> None:
    for flag in old:
        ap.add_argument(flag, dest=dest, action=_DeprecatedAlias, new=new, default=argparse.SUPPRESS,
                        help=argparse.SUPPRESS)


def add_output_dir(ap: argparse.ArgumentParser, default, help: str, old=("--output",)) -> None:
    """``--output-dir`` / ``-o``: the folder the results go to; ``old`` are hidden deprecated spellings."""
    ap.add_argument("--output-dir", "-o", default=default, help=help)
    _aliases(ap, "output_dir", "--output-dir", old)


def add_output_file(ap: argparse.ArgumentParser, default, help: str, old=()) -> None:
    """``--output`` / ``-o``: the one file the script writes; ``old`` are hidden deprecated spellings."""
    ap.add_argument("--output", "-o", default=default, help=help)
    _aliases(ap, "output", "--output", old)


def wrote(*paths) -> None:
    """``wrote PATH, PATH, ...`` (nothing when no path is given); arguments may be paths or lists of them."""
    flat = [str(p) for x in paths for p in (x if isinstance(x, (list, tuple)) else [x])]
    if flat:
        print("wrote " + ", ".join(flat))
