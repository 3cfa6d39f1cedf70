"""`python -m sim.evaluate`."""

import os
import sys

from sim.evaluate.cli import main

code = main()
if code > 128 and "ray" in sys.modules:
    # Stopped by a signal on the Ray engine: the records are written and the instance is taken down. End here:
    # Ray's native threads can still crash the interpreter's finalisation (SIGSEGV, exit -11) on a loaded machine.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
sys.exit(code)
