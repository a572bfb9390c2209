#!/bin/bash
# Re-creates the runs of docs/data/rt-reference into studies/rt-reference (full outputs;
# about 3 CPU hours in all; interFoam needs `apt-get install openfoam`).
# Usage: bash docs/data/rt-reference/run.sh   (from the repository root)
set -euo pipefail
OUT=studies/rt-reference
PY=${PY:-.venv/bin/python}
COMMON=(--set output.every=0 --set output.png=false --set output.fields=false
        --set output.particles=false --quiet --overwrite)
SIGNM='phases.heavy.region="y > -0.1*d*cos(2*pi*x/d)"'   # spike on the axis, bubbles at the walls
TAU2=(--set time.t_end=2.8284272)                         # tau = 2 (the 200 x 800 runs)
R=(--set mesh.diagonal=right)   # most runs use the 'right' diagonal (the lr runs below do not)
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
# the mirror-symmetric mesh (the scene's default)
R=()
run ls_lr_aco0.5 --set method.frame=eulerian --set time.courant=0.5 --set time.adaptive=true
run pf_lr_co0.5  --set time.courant=0.5
run ls_lr_co4    --set method.frame=eulerian --set time.courant=4
run pf_lr_co8    --set time.courant=8
# PFEM-2 with the scene's keys in h near the dt limit (to tau = 2.5), and with the lagged pressure
run pfh50_co0.125 --set time.courant=0.125 --set "mesh.cells=[50,200]"
run pfh100_co0.5  --set time.courant=0.5
run pfh200_co2    --set time.courant=2 --set "mesh.cells=[200,800]"
run pfh100_co8
LAG='flow.explicit_pressure="lagged"'
run pfh50_co0.125_lagged --set time.courant=0.125 --set "mesh.cells=[50,200]" --set "$LAG"
run pfh100_co0.5_lagged  --set time.courant=0.5 --set "$LAG"
run pfh200_co2_lagged    --set time.courant=2 --set "mesh.cells=[200,800]" --set "$LAG" \
  || echo "pfh200_co2_lagged: diverged (as stored: at tau = 1.89)"
run pfh100_co8_lagged    --set "$LAG"
# interFoam (OpenFOAM v1912): centred spike at dt = 0.001, and 200 x 800 at dt = 0.004 to tau = 2
CASE=("$PY" benchmarks/interfoam_case.py)
"${CASE[@]}" make "$OUT/interfoam/s100_dt0.001_signm" --nx 100 --ny 400 --dt 0.001 --sign -1 --overwrite
"${CASE[@]}" make "$OUT/interfoam/f200_dt0.004" --nx 200 --ny 800 --dt 0.004 --tau-end 2 --overwrite
# 50 x 200 at dt = 0.001 to tau = 2: flipped, and the sides as symmetry planes
"${CASE[@]}" make "$OUT/interfoam/r050_dt0.001_signm" --nx 50 --ny 200 --dt 0.001 --tau-end 2 \
  --sign -1 --overwrite
"${CASE[@]}" make "$OUT/interfoam/r050_dt0.001_sym" --nx 50 --ny 200 --dt 0.001 --tau-end 2 \
  --sides symmetry --overwrite
for c in s100_dt0.001_signm f200_dt0.004 r050_dt0.001_signm r050_dt0.001_sym; do
  "${CASE[@]}" run "$OUT/interfoam/$c" --tlim 6000
done
