#!/bin/bash
# Re-creates the runs of docs/data/rt-reference into studies/rt-reference (full outputs;
# session 4 of issue 5; ~2.5 CPU hours in all).
# Usage: bash studies/rt-reference/run.sh [PEER_DIR]   (from the repository root)
# PEER_DIR: the interFoam peer folder with make_case.py / tips.py (default ../shared/peers/interfoam-rt)
set -euo pipefail
PEER=$(realpath "${1:-../shared/peers/interfoam-rt}")
OUT=studies/rt-reference
PY=${PY:-.venv/bin/python}
COMMON=(--set output.every=0 --set output.png=false --set output.fields=false
        --set output.particles=false --quiet --overwrite)
SIGNM='phases.heavy.region="y > -0.1*d*cos(2*pi*x/d)"'   # spike on the axis, bubbles at the walls
TAU2=(--set time.t_end=2.8284272)                         # tau = 2 (the 200 x 800 runs)
R=(--set mesh.diagonal=right)   # the runs of session 4 before the scene moved to left/right
run() { name=$1; shift; echo "$(date +%T) $name"; "$PY" -m pfem2x run rayleigh-taylor "${R[@]}" "$@" "${COMMON[@]}" --out "$OUT/pfem2x/$name"; }
# level set at a true Courant number <= 0.5 (adaptive dt), three grids, both signs
run ls50_aco0.5   --set method.frame=eulerian --set time.courant=0.5 --set time.adaptive=true --set "mesh.cells=[50,200]"
run ls_aco0.5     --set method.frame=eulerian --set time.courant=0.5 --set time.adaptive=true
run ls200_aco0.5  --set method.frame=eulerian --set time.courant=0.5 --set time.adaptive=true --set "mesh.cells=[200,800]" "${TAU2[@]}"
run ls_aco0.5_signm --set method.frame=eulerian --set time.courant=0.5 --set time.adaptive=true --set "$SIGNM"
run ls_co0.5_signm  --set method.frame=eulerian --set time.courant=0.5 --set "$SIGNM"
# PFEM-2
run pf50_co0.25    --set time.courant=0.25 --set "mesh.cells=[50,200]"
run pf_co0.5_signm --set time.courant=0.5 --set "$SIGNM"
run pf200_co4      --set time.courant=4 --set "mesh.cells=[200,800]" "${TAU2[@]}"
# level-set bubble: density smoothing, re-distancing, SUPG (50 x 200, dt = 0.00707)
L50=(--set method.frame=eulerian --set time.courant=0.25 --set "mesh.cells=[50,200]")
run ls50_co0.25   "${L50[@]}"
run ls50_w0.75    "${L50[@]}" --set flow.interface_width=0.75
run ls50_w3       "${L50[@]}" --set flow.interface_width=3.0
run ls50_noreinit "${L50[@]}" --set flow.reinit_every=0
run ls50_nosupg   "${L50[@]}" --set method.supg=false
# the mirror-symmetric mesh (the scene's default now)
R=()
run ls_lr_aco0.5 --set method.frame=eulerian --set time.courant=0.5 --set time.adaptive=true
run pf_lr_co0.5  --set time.courant=0.5
run ls_lr_co4    --set method.frame=eulerian --set time.courant=4
run pf_lr_co8    --set time.courant=8
# interFoam (OpenFOAM v1912): centred spike at dt = 0.001, and 200 x 800 at dt = 0.004 to t = 2.9
WORK=$(mktemp -d)
cd "$WORK"
python3 "$PEER/make_case.py" s100_dt0.001_signm --nx 100 --ny 400 --dt 0.001 --sign -1
python3 "$PEER/make_case.py" f200_dt0.004 --nx 200 --ny 800 --dt 0.004 --end 2.9
for c in s100_dt0.001_signm f200_dt0.004; do
  TLIM=6000 ./$c/Allrun && python3 "$PEER/tips.py" $c --quiet
  mkdir -p "$OLDPWD/$OUT/interfoam/$c" && cp $c/tips.csv $c/wallclock.txt "$OLDPWD/$OUT/interfoam/$c/"
done
