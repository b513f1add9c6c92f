"""`python -m tkujax.cli`: the `tkujax` command (`tkujax.console`: a Ctrl-C while it loads
exits as one later does, one line, exit 130, no traceback)."""

import sys

from tkujax.console import main

sys.exit(main())
