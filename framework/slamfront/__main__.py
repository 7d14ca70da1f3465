"""``python -m slamfront ...`` is the ``slamfront`` command."""

import sys

from slamfront.cli import main

sys.exit(main())
