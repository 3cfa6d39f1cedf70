"""`python -m sim.evaluate`."""

import sys

from sim.evaluate.cli import main

sys.exit(main())
