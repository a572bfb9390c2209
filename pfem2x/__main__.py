"""``python -m pfem2x`` = the ``pfem2x`` command."""

import sys

from pfem2x.cli import main

sys.exit(main())
