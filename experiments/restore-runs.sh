#!/usr/bin/env bash
# Puts the exported runs (EXPORT, default pretrained/) back where reproduce-all.sh trains them
# (OUT, default results/), so that on a new machine the queue skips what is finished and resumes
# what is not from its exported checkpoint. A run directory already under OUT is left alone.
# Figures 7 and 8 and the course's tuning runs are not exported (their curves and tables are in
# experiments/): on a new machine reproduce-all.sh trains them again, unless START names a later
# step (e.g. START=table1-rest, from Table 1's last tasks on). The shared-courses tuning runs are
# fig11-shared's seed 0, exported with it.
#
#   bash experiments/restore-runs.sh && START=table1-rest bash experiments/reproduce-all.sh
set -euo pipefail
OUT=${OUT:-results}
EXPORT=${EXPORT:-pretrained}
restore() {  # restore SOURCE_DIR TARGET_DIR [PREFIX [GLOB]]: each SOURCE_DIR/<GLOB> run to TARGET_DIR/<PREFIX><run>
    local source=$1 target=$2 prefix=${3:-} glob=${4:-*}
    [ -d "$source" ] || return 0
    mkdir -p "$target"
    for run in "$source"/$glob/; do
        run=${run%/}
        [ -d "$run/checkpoints" ] || continue
        local dest="$target/$prefix$(basename "$run")"
        if [ -e "$dest" ]; then
            echo "kept     $dest"
        else
            cp -r "$run" "$dest" && echo "restored $dest"
        fi
    done
}
restore "$EXPORT/dcs" "$OUT/table1" dcs-                 # reproduce table1 names its runs dcs-<task>[-cnn]-seed<k>
# (pretrained/dcs-position-ties is not restored: runs of an earlier ranking that Table 1 trains again)
restore "$EXPORT/quadruped" "$OUT/fig11"                 # fig11's runs and table2's beside them
restore "$EXPORT/quadruped-turn" "$OUT/fig11-turn" "" "quadruped-walls-*"   # fig11-turn's runs
restore "$EXPORT/quadruped-turn" "$OUT/turn" "" "quadruped-turn-*"            # the run its low level came from
restore "$EXPORT/quadruped-shared" "$OUT/fig11-shared"  # Figure 11 on shared courses (seed 0 began as a tuning run)
restore "$EXPORT/quadruped-400" "$OUT/fig11-400"         # Figure 11's runs continued to 400 iterations
restore "$EXPORT/quadruped-gates" "$OUT/gates"          # the gates corridor (reproduce gates)
restore "$EXPORT/dcs-fs2" "$OUT/table1-fs2" dcs-         # Table 1 at its second setting (table1-fs2)
