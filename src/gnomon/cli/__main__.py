"""``python -m gnomon.cli ARGS``: the same as ``gnomon ARGS``."""

import sys

from gnomon.cli import main

sys.exit(main())
