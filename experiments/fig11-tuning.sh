#!/usr/bin/env bash
# Choosing the ES settings of the quadruped-walls presets (issue 24) before Figure 11's runs:
# short runs of the IAP and the CNN high level (seed 0, 30 ES iterations each), three settings
# of learning rate and sigma. The setting with the best evaluation return (the mean of the last
# five iterations' evaluations, each 8 episodes, then the mean over the two policies) becomes
# COURSE_ES (iap_mjx/configs/quadruped_presets.py) for every walls and
# gates preset, seed and figure; the blind control is never tuned on. Each run's config.json
# and metrics.csv are copied to experiments/fig11-tuning/<run>/ for RESULTS.md;
# `python experiments/fig11_tuning_report.py` prints their table and the setting the rule chooses.
#
#   bash experiments/fig11-tuning.sh          # from the repository's root, in its venv (~1.5 h alone)
#
# Settings (environment variables): OUT (default results/fig11-tuning), NICE (default 10).
set -uo pipefail
OUT=${OUT:-results/fig11-tuning}
NICE=${NICE:-10}
KEEP=experiments/fig11-tuning
for high in iap cnn; do
    for setting in "lr02-s05 es.learning_rate=0.02 es.sigma=0.05" \
                   "lr05-s05 es.learning_rate=0.05 es.sigma=0.05" \
                   "lr10-s10 es.learning_rate=0.1 es.sigma=0.1"; do
        read -r name overrides <<< "$setting"
        run="$high-$name"
        echo "== $(date -u '+%F %T') $run: iap-mjx train quadruped-walls-$high run.iterations=30 $overrides"
        # shellcheck disable=SC2086  # the overrides are separate words
        nice -n "$NICE" iap-mjx train "quadruped-walls-$high" run.iterations=30 $overrides \
            --run-dir "$OUT/$run" --no-progress
        status=$?  # read before the echo's $(date) replaces it
        echo "== $(date -u '+%F %T') exit $status"
        mkdir -p "$KEEP/$run" && cp "$OUT/$run/config.json" "$OUT/$run/metrics.csv" "$KEEP/$run/"
    done
done
