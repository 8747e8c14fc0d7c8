"""`python -m gprbot`: the same as the `gprbot` command."""

import sys

from gprbot.cli import main

sys.exit(main())
