"""``vdm-aero``: the command line, and the composition root of the project.

User errors (``UserInputError``) print one line to stderr and exit with code 2; anything else is a
bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from vdm_aero.errors import UserInputError
from vdm_aero_cli import (
    cmd_bench,
    cmd_calibrate,
    cmd_data,
    cmd_demo,
    cmd_model,
    cmd_replay,
    cmd_serve,
    cmd_sitl,
    discover,
    paper,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vdm-aero",
        description="Sparse pressure-port aerodynamics for UAV vehicle-dynamic-model navigation.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    cmd_data.register(sub)
    cmd_model.register(sub)
    paper.register(sub)
    discover.register(sub)
    cmd_sitl.register(sub)
    cmd_serve.register(sub)
    cmd_calibrate.register(sub)
    cmd_replay.register(sub)
    cmd_bench.register(sub)
    cmd_demo.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        rc = args.func(args)
    except UserInputError as e:
        print(f"vdm-aero: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("vdm-aero: interrupted", file=sys.stderr)
        return 130
    return int(rc or 0)


if __name__ == "__main__":
    sys.exit(main())
