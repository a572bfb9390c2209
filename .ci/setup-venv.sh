#!/usr/bin/env bash
# A venv from Debian's Python (it sees python3-dolfinx), pip packages pinned
# to the system numpy (numpy 2 would break Debian's petsc4py).
set -euo pipefail
VENV=${1:-.venv}
SYSPY=/usr/bin/python3
[ -x "$VENV/bin/python" ] || $SYSPY -m venv --system-site-packages "$VENV"
NPV=$("$VENV/bin/python" -c "import numpy; print(numpy.__version__)")
CONS=$(mktemp); trap 'rm -f "$CONS"' EXIT
echo "numpy==$NPV" > "$CONS"
"$VENV/bin/python" -m pip install -q --upgrade -c "$CONS" pip >/dev/null
"$VENV/bin/python" -m pip install -q -c "$CONS" -e ".[viz,test]"
"$VENV/bin/python" -c "import pfem2x.compat as c; print('pfem2x: DOLFINx', c.dolfinx.__version__, 'in', '$VENV')"
