"""``python -m splitrender`` runs the command line."""

import sys

from splitrender.cli import main

sys.exit(main())
