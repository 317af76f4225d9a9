#!/bin/bash
# Reward and prediction designs, issue 32 (reduced budget, shared machine): --preset paper, 15 m/s,
# on top of the best state design of the issue-16 ablation (no grid, densest direction within 1.5 km),
# 3 seeds x 1000 episodes, 50 greedy evaluation episodes per seed; one training at a time (--workers 1)
set -e  # run from the repository root, its venv active
run() { name=$1; shift
  nice -n 10 truav experiment velocity --preset paper --schemes truav --speeds 15 \
    --seeds 3 --seeds-per-cell 3 --episodes 1000 --eval-episodes 50 --window 200 --workers 1 \
    --quiet --out runs/abl3/$name --set learner.grid_cells=1 --set learner.sense_range_m=1500 "$@"; }
# the paper's budget (10 seeds x 5000 episodes, 100 evaluation episodes per seed), at 15 m/s only
paper() { name=$1; shift
  nice -n 10 truav experiment velocity --preset paper --schemes truav --speeds 15 --window 500 --workers 1 \
    --quiet --out runs/abl3/paper_$name --set learner.grid_cells=1 --set learner.sense_range_m=1500 "$@"; }
DIFF="--set learner.w_coverage=0 --set learner.w_overlap=0 --set learner.w_difference=0.25"
for v in "$@"; do
  case $v in
    best) run best ;;
    diff) run diff $DIFF ;;
    shape) run shape --set learner.w_shaping=1.0 ;;
    predict) run predict --set learner.predict_sectors=4 ;;
    diff_shape) run diff_shape $DIFF --set learner.w_shaping=1.0 ;;
    diff1) run diff1 --set learner.w_coverage=0 --set learner.w_overlap=0 --set learner.w_difference=1.0 ;;
    diff_keep) run diff_keep --set learner.w_difference=0.25 ;;
    shape025) run shape025 --set learner.w_shaping=0.25 ;;
    shape4) run shape4 --set learner.w_shaping=4.0 ;;
    predict_d095) run predict_d095 --set learner.predict_sectors=4 --set learner.predict_decay=0.95 ;;
    predict_nosense) run predict_nosense --set learner.sense_range_m=0 --set learner.predict_sectors=4 ;;
    all) run all $DIFF --set learner.w_shaping=1.0 --set learner.predict_sectors=4 ;;
    paper_best) paper best ;;
    paper_diff) paper diff $DIFF ;;
    paper_shape) paper shape --set learner.w_shaping=1.0 ;;
    paper_predict) paper predict --set learner.predict_sectors=4 ;;
    paper_diff_shape) paper diff_shape $DIFF --set learner.w_shaping=1.0 ;;
  esac
done
