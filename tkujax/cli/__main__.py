"""`python -m tkujax.cli`: the `tkujax` command (a Ctrl-C while it loads exits as one
later does: one line, exit 130, no traceback)."""

import sys

try:
    from tkujax.cli import main
except KeyboardInterrupt:
    print("tkujax: interrupted; rerun the same command to resume", file=sys.stderr)
    sys.exit(130)

sys.exit(main())
