"""The ``splitspec`` command line.

Every subcommand catches splitspec's own errors at this boundary: one line on
stderr (``splitspec: error: ...``) and exit status 2 for bad input, 1 for a
failed run; no traceback (set ``SPLITSPEC_DEBUG=1`` to see one).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys

from splitspec_core.errors import SplitspecError

EXIT_BAD_INPUT = 2
EXIT_FAILED = 1


def _cmd_design(args: argparse.Namespace) -> int:
    from splitspec_core.design import design
    from splitspec_core.report import design_json, design_text
    from splitspec_core.scenario import load_scenario

    sc = load_scenario(args.scenario)
    des = design(sc, compare_q_methods=not args.json)
    if args.json:
        json.dump(design_json(des), sys.stdout, indent=None if args.compact else 2)
        sys.stdout.write("\n")
    else:
        print(design_text(des))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="splitspec",
        description="Split-spectrum distributed state estimation: design, simulate, deploy.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log more")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("design", help="check the assumptions and design K_i, V_i, P_i and g or q",
                       description="Check a scenario's assumptions and design the estimator "
                                   "(per-agent V_i, P_i, K_i; g or q with the bound it certifies).")
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--json", action="store_true", help="print the design as one JSON object")
    p.add_argument("--compact", action="store_true", help="with --json: no indentation")
    p.set_defaults(func=_cmd_design)
    return parser


def main(argv: list | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        return int(args.func(args) or 0)
    except SplitspecError as exc:
        if os.environ.get("SPLITSPEC_DEBUG"):
            raise
        print(f"splitspec: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("splitspec: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
