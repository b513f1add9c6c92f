"""`python -m tkujax.cli`: the `tkujax` command."""

import sys

from tkujax.cli import main

sys.exit(main())
