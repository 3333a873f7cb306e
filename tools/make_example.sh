#!/usr/bin/env bash
# Remake the bundled example in maps/ with the project's own tools (same seeds, same files).
set -euo pipefail
cd "$(dirname "$0")/.."
mf=.venv/bin/mapfilter
survey=$(mktemp -d)/office_survey.txt.gz
.venv/bin/python tools/draw_office.py --out maps/office_plan.png --aps maps/office_aps.csv --seed 7
$mf map prepare maps/office_plan.png --resolution 0.05 --map-resolution 0.1 \
    --floor office --access-points maps/office_aps.csv --out maps/office.yaml
# a 2-minute walk (ground truth at every step) and a radio-map survey on a 2 m grid
$mf simulate maps/office.yaml --out maps/office_walk.txt.gz --duration 120 --seed 1
$mf simulate maps/office.yaml --out "$survey" --survey --seed 2
$mf radiomap build maps/office.yaml "$survey" --out maps/office_radiomap.npz
# access points located and path-loss parameters fitted from the survey alone (trilateration)
$mf radiomap fit-aps maps/office.yaml "$survey" --out maps/office_fitted_aps.csv
rm -f "$survey"
