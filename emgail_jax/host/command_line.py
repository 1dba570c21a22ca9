"""The parser of every command line here: bad input is one line on stderr and exit code 2."""

from __future__ import annotations

import argparse


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser whose refusals are one line, as the commands' own: ``error:``, what
    to fix, and where the usage is (``--help``, which still prints it whole)."""

    def error(self, message: str):
        self.exit(2, f"error: {message} (usage: {self.prog} --help)\n")


def add_run_and_seed(parser: argparse.ArgumentParser) -> None:
    """The run directory and ``--seed`` of a command that reads a run's rewards."""
    parser.add_argument("run_dir")
    parser.add_argument(
        "--seed",
        type=int,
        default=None,
        help="one run seed, as run --seed numbers it (default: all)",
    )
