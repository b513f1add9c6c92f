"""`python -m tkujax.cli`: the `tkujax` command (`tkujax.console`: a Ctrl-C while it loads
exits as one later does, one line, exit 130, no traceback)."""

import signal
import sys

from tkujax.console import EXIT_INTERRUPTED, main

try:
    code = main()
except KeyboardInterrupt:       # one already on its way when the command ended as interrupted
    code = EXIT_INTERRUPTED
finally:
    # The command has ended and said so: a Ctrl-C landing while Python exits no longer
    # changes its exit code (`tkujax.cli.errors.cancel_redeliveries`, INTERRUPT_HANDLED).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
sys.exit(code)
