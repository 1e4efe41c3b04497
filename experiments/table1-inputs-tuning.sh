#!/usr/bin/env bash
# Table 1's second short test (issue 26, RESULTS.md section `table1-inputs-tuning`, its rule
# fixed before these runs): on cartpole-swingup and reacher-easy, seed 0, 30 ES iterations each,
# the table's setting (baseline) against two candidates, then each run's final centre evaluated
# on the same 100 episodes (`iap-mjx eval --episodes 100`, evaluation seed 2021, the training
# condition). Each run's config.json, metrics.csv and eval-100.json are copied to
# experiments/table1-inputs-tuning/<run>/; `python experiments/table1_paired_report.py` prints
# the rule's table.
#
#   bash experiments/table1-inputs-tuning.sh   # from the repository's root, in its venv (~1 h alone)
#
# Settings (environment variables): OUT (default results/table1-inputs-tuning), NICE (default 10).
set -uo pipefail
OUT=${OUT:-results/table1-inputs-tuning}
NICE=${NICE:-10}
KEEP=experiments/table1-inputs-tuning
for task in cartpole-swingup reacher-easy; do
    for setting in "base" \
                   "episodes2 es.n_episodes=2" \
                   "fs2-patches env.frame_stack=2 policy.with_patches=true"; do
        read -r name overrides <<< "$setting"
        run="$name-$task"
        echo "== $(date -u '+%F %T') $run: iap-mjx train dcs-$task run.iterations=30 ${overrides:-}"
        # shellcheck disable=SC2086  # the overrides are separate words
        nice -n "$NICE" iap-mjx train "dcs-$task" run.iterations=30 ${overrides:-} \
            --run-dir "$OUT/$run" --no-progress
        status=$?  # read before the echo's $(date) replaces it
        echo "== $(date -u '+%F %T') exit $status"
        if [ ! -s "$OUT/$run/eval-100.json" ]; then
            nice -n "$NICE" iap-mjx eval "$OUT/$run" --episodes 100 > "$OUT/$run/eval-100.json.tmp" \
                && mv "$OUT/$run/eval-100.json.tmp" "$OUT/$run/eval-100.json"
        fi
        mkdir -p "$KEEP/$run" && cp "$OUT/$run/config.json" "$OUT/$run/metrics.csv" "$OUT/$run/eval-100.json" "$KEEP/$run/"
    done
done
