"""`python -m fabline` runs the command line."""

import sys

from fabline.cli import main

sys.exit(main())
