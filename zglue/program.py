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
import ctypes
import functools
import logging
import os
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


#: glibc's mallopt parameters M_TRIM_THRESHOLD and M_MMAP_THRESHOLD, and the value every program pins both to
#: (glibc's own initial values)
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD_BYTES = 128 * 1024


def pin_mmap_threshold(nbytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Pin glibc's mmap threshold (allocations this large or larger are mmapped and unmapped when freed); True if set.

    Why (issue 30, measured with bench/rss_probe.py): glibc starts the threshold at 128 KiB and raises it to the size
    of any mmapped block freed, up to 32 MiB. After the first message of about 1 MiB (a large mission, or the
    fuzzer's oversized ones) every later one is carved from the heap of the zenoh thread that receives it, and each
    thread's arena keeps that memory: an agent under `vsfleet fuzz` grew RssAnon +2.7 MiB in its first minute
    (+0.13 MiB with the threshold pinned), a router under steady fuzz traffic +2.4 MiB over 4 minutes (+0.62 with
    both thresholds pinned, flat after 24 s). Setting it also turns glibc's adjustment off. The trim threshold (free memory
    at the top of a heap above which it is given back) is set back to the same value: an adjustment made before
    this call (a large block freed while Python imported its modules) left it at twice that block. Left alone if
    the environment sets either (MALLOC_MMAP_THRESHOLD_, MALLOC_TRIM_THRESHOLD_) or the C library has no mallopt
    (not glibc)."""
    if "MALLOC_MMAP_THRESHOLD_" in os.environ or "MALLOC_TRIM_THRESHOLD_" in os.environ:
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(M_MMAP_THRESHOLD, nbytes)) and bool(mallopt(M_TRIM_THRESHOLD, nbytes))


def program(build_parser: Callable[[], argparse.ArgumentParser], log: logging.Logger,
            prefix: str = "") -> Callable[[Callable[[argparse.Namespace], int | None]], Callable[..., int]]:
    """Decorate a program's body into its ``main(argv=None) -> int`` (module docstring); ``prefix``
    goes before a refusal's line (e.g. ``cannot load scenario: ``)."""
    def wrap(body: Callable[[argparse.Namespace], int | None]) -> Callable[..., int]:
        @functools.wraps(body)
        def main(argv: list[str] | None = None) -> int:
            args = build_parser().parse_args(argv)
            init_logging(getattr(args, "verbose", False))
            pin_mmap_threshold()
            try:
                return int(body(args) or 0)
            except Refused as exc:
                log.error("%s%s", prefix, exc)
                return 2
        return main
    return wrap
