"""The command line's shared parts: exit codes, the argparse parser with the bad-input contract,
option types, and the progress lines and default output folders of the sub-commands."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import NoReturn

from kinadapt_nn.errors import did_you_mean

EXIT_OK, EXIT_NOT_SEATED, EXIT_BAD_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED = 0, 1, 2, 3, 130


class Parser(argparse.ArgumentParser):
    """argparse with the CLI's bad-input contract: one line on stderr, exit 2 (no usage dump)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"kinadapt: error: {message} (see {self.prog} --help)\n")

    def _check_value(self, action: argparse.Action, value) -> None:
        """argparse's check of a choice (a subcommand, ``--executor``), naming the closest valid one."""
        try:
            super()._check_value(action, value)
        except argparse.ArgumentError:
            hint = did_you_mean(value, action.choices) if isinstance(value, str) else ""
            if not hint:
                raise
            raise argparse.ArgumentError(action, f"invalid choice: {value!r}; {hint} (choose from "
                                                 f"{', '.join(map(repr, action.choices))})") from None


def _number_in(convert: type, noun: str, lo: float, hi: float, lo_open: bool):
    """argparse type: ``convert(text)`` (``int`` or ``float``, called ``noun`` in the message), finite,
    in [lo, hi], or (lo, hi] with ``lo_open``."""

    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {noun}") from None
        if not (math.isfinite(value) and (lo < value if lo_open else lo <= value) and value <= hi):
            raise argparse.ArgumentTypeError(f"{text.strip()} is outside {'(' if lo_open else '['}{lo:g}, {hi:g}]")
        return value

    return parse


def int_in(lo: int, hi: int):
    """argparse type: an integer in [lo, hi]."""
    return _number_in(int, "an integer", lo, hi, lo_open=False)


def float_in(lo: float, hi: float):
    """argparse type: a finite number in (lo, hi] (lo excluded: every such option is a positive quantity)."""
    return _number_in(float, "a number", lo, hi, lo_open=True)


class Once(argparse.Action):
    """argparse action of an option that takes one value: given twice it is an error, not silently the last."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        if getattr(namespace, self.dest, None) is not None:
            raise argparse.ArgumentError(self, f"given twice ({getattr(namespace, self.dest)!r} and {values!r}); "
                                               "give it once")
        setattr(namespace, self.dest, values)


class Lazy:
    """A help-text parameter computed when argparse formats the help (``%(name)s``)."""

    def __init__(self, fn) -> None:
        self.fn = fn

    def __str__(self) -> str:
        return self.fn()


def progress_printer(args: argparse.Namespace, name: str):
    """A ``progress(msg)`` callable: one time-stamped line on stderr per step, silent with --quiet."""
    t0 = time.perf_counter()

    def progress(msg: str) -> None:
        if not args.quiet:
            print(f"kinadapt {name} [{time.perf_counter() - t0:5.1f} s] {msg}", file=sys.stderr, flush=True)

    return progress


def default_out(kind: str) -> Path:
    return Path("runs") / f"{kind}-{time.strftime('%Y%m%d-%H%M%S')}"


def with_monitor(cfg, args: argparse.Namespace):
    """``--monitor`` of ``compare`` and ``sweep``: their job config (a ``base`` list of online config
    keys) with ``monitor.enabled=true`` added, and the worker set-up that registers the live monitor
    with the episode loop in each worker process (``runs.jobs.Runner``'s ``setup``). -> (cfg, setup or
    None); without ``--monitor``: (cfg, None)."""
    if not getattr(args, "monitor", False):
        return cfg, None
    from functools import partial

    from kinadapt_nn.monitor.monitor import monitor_of_run  # (importing it registers it in this process)
    from kinadapt_nn.runs.loop import register_monitor

    return cfg.model_copy(update={"base": [*cfg.base, "monitor.enabled=true"]}), partial(register_monitor,
                                                                                         monitor_of_run)
