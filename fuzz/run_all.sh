#!/bin/sh
# Runs every fuzz target in turn for SECONDS each (default 180), one process, with the memory
# limits the targets must hold to; logs to logs/<target>.log, crashes to artifacts/<target>/.
# Build first: cargo +nightly fuzz build -O   (from fuzz/ or the repository root)
# Usage: fuzz/run_all.sh [SECONDS] [TARGET...]
set -u
cd "$(dirname "$0")"
secs=${1:-180}
[ $# -gt 0 ] && shift
targets=${*:-"transforms_json paper_npz colmap_model npy exr png ply train_config edit_spec checkpoint run_info"}
bin=target/x86_64-unknown-linux-gnu/release
mkdir -p logs
for t in $targets; do
    mkdir -p "artifacts/$t" "corpus/$t"
    RAYON_NUM_THREADS=1 "$bin/$t" "corpus/$t" -artifact_prefix="artifacts/$t/" \
        -max_total_time="$secs" -rss_limit_mb=2048 -malloc_limit_mb=2048 -timeout=10 \
        -print_final_stats=1 >"logs/$t.log" 2>&1
    echo "$t: exit $? $(grep -E '^#[0-9]+' "logs/$t.log" | tail -1)"
done
