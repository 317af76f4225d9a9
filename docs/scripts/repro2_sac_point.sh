#!/bin/bash
# one SAC sweep point (issue 16 part 4): held-out seeds 100-101, 300 episodes, 15 m/s, --preset paper (central.geofence on)
set -e  # run from the repository root, its venv active
name=$1; shift
nice -n 10 truav experiment velocity --preset paper --schemes central --speeds 15 \
    --seeds 2 --seed-start 100 --seeds-per-cell 2 --episodes 300 --eval-episodes 30 --window 100 --workers 1 \
    --quiet --out runs/sac3/$name "$@"
