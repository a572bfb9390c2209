#!/usr/bin/env bash
# DOLFINx 0.11 from the PyPI wheel dolfinx-solver-real, in a Python 3.12 venv.
set -euo pipefail
VENV=${1:-.venv-011}
PY312=""
if command -v pyenv >/dev/null && [ -x "$(pyenv root)/versions/3.12.1/bin/python" ]; then
  PY312="$(pyenv root)/versions/3.12.1/bin/python"
elif [ -x "$HOME/.pyenv/versions/3.12.1/bin/python" ]; then
  PY312="$HOME/.pyenv/versions/3.12.1/bin/python"
elif command -v python3.12 >/dev/null; then
  PY312=$(command -v python3.12)
else
  echo "error: no Python 3.12 found (pyenv 3.12.1 or python3.12 on PATH)" >&2; exit 1
fi
[ -x "$VENV/bin/python" ] || "$PY312" -m venv "$VENV"
"$VENV/bin/python" -m pip install -q --upgrade pip >/dev/null
"$VENV/bin/python" -m pip install -q dolfinx-solver-real numba gmsh
"$VENV/bin/python" -m pip install -q -e ".[viz,test]"
"$VENV/bin/python" -c "import pfem2x.compat as c; print('pfem2x: DOLFINx', c.dolfinx.__version__, 'in', '$VENV')"
