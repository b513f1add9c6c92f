"""`python -m tkujax.bench [options]`: the same as `tkujax bench [options]`."""

import argparse
import sys

from tkujax.bench.cli import add_bench_command


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tkujax.bench")
    sub = parser.add_subparsers(dest="command", required=True)
    add_bench_command(sub)
    args = parser.parse_args(["bench", *(sys.argv[1:] if argv is None else argv)])
    try:
        return args.func(args)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
