"""``python -m pfem2x`` = the ``pfem2x`` command."""

from pfem2x.cli import entry

entry()
