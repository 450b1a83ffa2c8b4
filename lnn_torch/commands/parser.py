"""The argument parser of the commands that are not Lightning's."""

from __future__ import annotations

import argparse


class CommandParser(argparse.ArgumentParser):
    """A command's parser whose error is one line with the pointer to ``--help`` (argparse prints the whole usage
    first: 27 lines for ``import``)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (options: {self.prog} --help)\n")
