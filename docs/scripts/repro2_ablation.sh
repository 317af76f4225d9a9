#!/bin/bash
# State-design ablation, issue 16 part 2 (reduced budget, the shared machine was at load 50-65):
# --preset paper, 15 m/s, 3 seeds x 1000 episodes, 50 greedy evaluation episodes per seed
set -e  # run from the repository root, its venv active
run() { name=$1; shift
  nice -n 10 truav experiment velocity --preset paper --schemes truav --speeds 15 \
    --seeds 3 --seeds-per-cell 3 --episodes 1000 --eval-episodes 50 --window 200 --workers 1 \
    --quiet --out runs/abl/$name "$@"; }
for v in "$@"; do
  case $v in
    base) run base ;;
    sense1500) run sense1500 --set learner.sense_range_m=1500 ;;
    grid5_sense1500) run grid5_sense1500 --set learner.grid_cells=5 --set learner.sense_range_m=1500 ;;
    nbdir4) run nbdir4 --set learner.neighbour_sectors=4 ;;
    grid5) run grid5 --set learner.grid_cells=5 ;;
    grid20) run grid20 --set learner.grid_cells=20 ;;
    dens8) run dens8 --set 'learner.density_edges=[1,3,6,10,15,25,40]' ;;
    grid5_sense2500) run grid5_sense2500 --set learner.grid_cells=5 --set learner.sense_range_m=2500 ;;
    grid5_sense1500_nbdir4) run grid5_sense1500_nbdir4 --set learner.grid_cells=5 --set learner.sense_range_m=1500 --set learner.neighbour_sectors=4 ;;
    grid1_sense1500) run grid1_sense1500 --set learner.grid_cells=1 --set learner.sense_range_m=1500 ;;
    grid1_sense2500) run grid1_sense2500 --set learner.grid_cells=1 --set learner.sense_range_m=2500 ;;
    grid1_sense2500_nbdir4) run grid1_sense2500_nbdir4 --set learner.grid_cells=1 --set learner.sense_range_m=2500 --set learner.neighbour_sectors=4 ;;
    grid1) run grid1 --set learner.grid_cells=1 ;;
  esac
done
