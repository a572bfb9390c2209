"""The ``pfem2x study`` sub-command: its options and its exit codes."""

from __future__ import annotations

import argparse
import signal
import sys
from typing import Any

from pfem2x.scene import SceneError
from pfem2x.study.driver import EXIT_BAD_INPUT, EXIT_INTERRUPTED, run_study


def add_study_parser(sub: Any) -> argparse.ArgumentParser:
    """Add the ``study`` sub-command to ``sub`` (an argparse sub-parsers object)."""
    s = sub.add_parser(
        "study",
        help="run the product of --vary lists of a scene; tabulate and plot error against time",
    )
    s.add_argument("scene", help="a scene file (.toml) or a built-in scene name")
    s.add_argument(
        "--vary",
        action="append",
        required=True,
        metavar="KEY=V1,V2,...",
        help="a key and its values (TOML; commas inside [...] do not split); keys varied "
        'together: K1,K2=[a1,b1],[a2,b2] (e.g. flow.extra_pass,flow.pressure_step=[false,"total"],'
        '[true,"increment"])',
    )
    s.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override for every run"
    )
    s.add_argument("--variant", help="apply the scene's [variants.NAME] (e.g. small)")
    s.add_argument("--jobs", type=int, default=1, help="variants run at once (default 1)")
    s.add_argument("--out", help="study folder (default studies/SCENE); reruns resume")
    s.add_argument("--metric", help="error metric plotted (default: l2_error_time_avg, ...)")
    s.add_argument("--quiet", action="store_true", help="no progress on stderr")
    return s


def study_main(args: argparse.Namespace) -> int:
    """Run ``pfem2x study`` from parsed arguments; return the exit code.

    SIGTERM is handled like Ctrl-C: the running children are killed, the tables
    of the finished variants written, exit 130.
    """

    def _term(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, _term)
    try:
        res = run_study(
            args.scene,
            args.vary,
            args.set,
            args.variant,
            jobs=args.jobs,
            out=args.out,
            metric=args.metric,
            quiet=args.quiet,
        )
    except SceneError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:  # before or after the children ran
        print("error: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        signal.signal(signal.SIGTERM, old)
    return res.exit_code
