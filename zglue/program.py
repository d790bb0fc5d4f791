"""The start-up every vsfleet program shares: its common flags, logging, and exit codes.

A program's ``build_parser`` ends with ``common_flags(p)`` (``--verbose`` and zenoh's flags), and
its ``main`` is its body under ``@program(build_parser, log)``::

    @program(build_parser, log)
    def main(args: argparse.Namespace) -> int:
        with refusing(ValueError):        # input refused before starting: one line, exit code 2
            check_name(args.robot, "robot")
        run_agent(zenoh_config(args), ...)  # the session opens through zconf.open_session
        return 0

``main(argv)`` parses ``argv``, starts logging (debug with ``--verbose``) and runs the body. Refused
(raised directly or through ``refusing``) is logged as one line and returns 2; everything else
reaches ``vsfleet`` (fleetctl/cli.py), which turns it into one line and its exit code.
"""

from __future__ import annotations

import argparse
import functools
import logging
from contextlib import contextmanager
from typing import Callable, Iterator

from .zconf import add_zenoh_args, init_logging


class Refused(Exception):
    """Input a program refuses before it starts (a flag, a file): one line, exit code 2."""


def common_flags(parser: argparse.ArgumentParser, zenoh: bool = True) -> argparse.ArgumentParser:
    """The end of every program's parser: ``--verbose`` (debug logging) and, unless the program opens
    no session, zenoh's flags (zconf.add_zenoh_args). Returns ``parser``."""
    parser.add_argument("--verbose", "-v", action="store_true", help="debug logging")
    if zenoh:
        add_zenoh_args(parser)
    return parser


@contextmanager
def refusing(*kinds: type[BaseException]) -> Iterator[None]:
    """Errors of ``kinds`` raised inside become Refused: the program says why in one line, exits 2."""
    try:
        yield
    except kinds as exc:
        raise Refused(str(exc)) from exc


def program(build_parser: Callable[[], argparse.ArgumentParser], log: logging.Logger,
            prefix: str = "") -> Callable[[Callable[[argparse.Namespace], int | None]], Callable[..., int]]:
    """Decorate a program's body into its ``main(argv=None) -> int`` (module docstring); ``prefix``
    goes before a refusal's line (e.g. ``cannot load scenario: ``)."""
    def wrap(body: Callable[[argparse.Namespace], int | None]) -> Callable[..., int]:
        @functools.wraps(body)
        def main(argv: list[str] | None = None) -> int:
            args = build_parser().parse_args(argv)
            init_logging(getattr(args, "verbose", False))
            try:
                return int(body(args) or 0)
            except Refused as exc:
                log.error("%s%s", prefix, exc)
                return 2
        return main
    return wrap
