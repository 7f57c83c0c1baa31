"""`python -m mjtrial.cli`: the `mjtrial` command, as the installed script runs it."""

import sys

from mjtrial.cli import main

sys.exit(main())
