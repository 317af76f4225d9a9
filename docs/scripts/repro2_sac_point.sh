#!/bin/bash
# one SAC sweep point (issue 16 part 4): 15 m/s, --preset paper (central.geofence on), held-out seeds from 100.
# Budget from the environment; the defaults are the first sweep's (2 seeds x 300 episodes, runs/sac3):
#   SAC_SEEDS=3 SAC_EPISODES=1000 SAC_EVAL=50 SAC_OUT=runs/sac1000 docs/scripts/repro2_sac_point.sh base
set -e  # run from the repository root, its venv active
name=$1; shift
seeds=${SAC_SEEDS:-2}
nice -n 10 truav experiment velocity --preset paper --schemes central --speeds 15 \
    --seeds "$seeds" --seed-start 100 --seeds-per-cell "$seeds" --episodes "${SAC_EPISODES:-300}" \
    --eval-episodes "${SAC_EVAL:-30}" --window 100 --workers 1 --quiet --out "${SAC_OUT:-runs/sac3}/$name" "$@"
