#!/usr/bin/env bash
# The default run from an empty cache, this tree against a reference commit: the default
# optimization (300 steps x 3 views, seed 0, the 256^3 aneurism from ../shared, ViT-B/32-shaped
# random CLIP weights) with examples/bench_optimize, built
#   - before: at a reference commit (default: the commit before the clip-simd merge, the last
#     one without the AVX-512 and bf16 CLIP kernels), in its own git worktree and target
#     directory;
#   - after: from this working tree;
# and run as: before f32, after f32, after --precision bf16 (skipped where the CPU lacks
# AVX512_BF16), one after the other, each with an empty caption-embedding cache (so the first
# use of the caption pool is timed too). Then the error between the runs' TFs (PSNR of renders
# from four held-out views, `bench_optimize --compare-tfs`), and a table.
#
# Usage, from anywhere in the repository (needs ../shared next to the repository root):
#     scripts/bench_default_run.sh [WORKDIR]
# WORKDIR (default: a new temporary directory) receives the worktree, builds, logs and TFs.
# Environment: BEFORE_REV overrides the "before" commit; THREADS sets rayon's thread count
# (default: rayon's choice, all cores); STEPS_ARGS adds flags to every bench_optimize run
# (only flags both builds know: the before build has no --precision, --steps or --compare-tfs).
# Run it on an idle machine: every row's wall time is only comparable if nothing else runs.
set -euo pipefail

repo=$(git rev-parse --show-toplevel)
cd "$repo"
work=${1:-$(mktemp -d -t t2tf-default-run.XXXXXX)}
mkdir -p "$work"
work=$(cd "$work" && pwd)

# The commit before the clip-simd merge: the first parent of the oldest first-parent merge of
# that branch into main.
if [[ -z "${BEFORE_REV:-}" ]]; then
    merge=$(git log --first-parent --merges --format=%H --grep="^Merge branch 'clip-simd'" | tail -n 1)
    if [[ -z "$merge" ]]; then
        echo "bench_default_run: no merge of 'clip-simd' in this history; set BEFORE_REV" >&2
        exit 1
    fi
    BEFORE_REV=$(git rev-parse "$merge^1")
fi
after_rev="$(git rev-parse --short HEAD)$(git diff --quiet HEAD -- || echo '+uncommitted')"
echo "before: $(git log -1 --format='%h %s' "$BEFORE_REV")"
echo "after:  $after_rev (this working tree)"
echo "work directory: $work"

# ../shared is found relative to the repository root by the benchmark: give the worktree one.
before_tree="$work/before"
if [[ ! -d "$before_tree" ]]; then
    git worktree add --detach "$before_tree" "$BEFORE_REV" >/dev/null
fi
ln -sfn "$repo/../shared" "$work/shared"

threads_args=()
if [[ -n "${THREADS:-}" ]]; then
    threads_args=(--threads "$THREADS")
fi

# The benchmarks need the `bench` feature; a tree older than that feature has none.
bench_features() {
    if grep -q '^bench = ' "$1/Cargo.toml"; then
        echo "--features=bench"
    fi
}
echo "building before ..." >&2
(cd "$before_tree" && CARGO_TARGET_DIR="$work/target-before" \
    cargo build --release --quiet $(bench_features "$before_tree") --example bench_optimize)
echo "building after ..." >&2
(cd "$repo" && CARGO_TARGET_DIR="$work/target-after" \
    cargo build --release --quiet --features bench --example bench_optimize)
before_bin="$work/target-before/release/examples/bench_optimize"
after_bin="$work/target-after/release/examples/bench_optimize"

bf16=yes
if ! grep -qw avx512_bf16 /proc/cpuinfo; then
    bf16=no
fi

# run NAME DIR BIN [FLAGS...]: the default run only (--no-grid), its TF saved as NAME.json,
# the caption cache empty (XDG_CACHE_HOME of its own).
run() {
    local name=$1 dir=$2 bin=$3
    shift 3
    rm -rf "$work/cache-$name" "$work/$name.json"
    echo "running $name ..." >&2
    (cd "$dir" && XDG_CACHE_HOME="$work/cache-$name" "$bin" --no-grid \
        --reference-tf "$work/$name.json" "${threads_args[@]}" ${STEPS_ARGS:-} "$@") \
        >"$work/$name.log" 2>"$work/$name.err"
}

run before-f32 "$before_tree" "$before_bin"
run after-f32 "$repo" "$after_bin" --precision f32
if [[ $bf16 == yes ]]; then
    run after-bf16 "$repo" "$after_bin" --precision bf16
fi

# Wall and CPU of the default run (init + loop), and the text phase (prompt, negatives and
# the 6,000-caption pool computed from scratch).
total() { grep -F '**total** (init + loop)' "$work/$1.log" | head -n 1; }
wall() { total "$1" | sed -E 's/.*\| \*\*([0-9.]+)\*\* \|.*/\1/'; }
cpu() { total "$1" | sed -E 's/.*CPU ([0-9.]+) s = ([0-9.]+) s on.*/\1/'; }
text() { grep -E '^text: ' "$work/$1.log" | sed -E 's/.* encoded in ([0-9.]+) s wall.*/\1/'; }
compare() {
    (cd "$repo" && "$after_bin" --compare-tfs "$work/$1.json" "$work/$2.json") |
        sed -E 's/.*PSNR held-out ([^ ]+) dB.*/\1/'
}

before_wall=$(wall before-f32)
echo
echo "CPU: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//'), $(nproc) CPUs"
echo "threads: ${THREADS:-all (rayon default)}; load average now: $(cut -d' ' -f1-3 /proc/loadavg)"
echo
echo "| build | precision | text incl. pool first use (s) | run wall, init + loop (s) | CPU (s) | wall vs before | held-out PSNR vs before f32 (dB) |"
echo "|---|---|---|---|---|---|---|"
row() {
    local name=$1 build=$2 prec=$3 w
    w=$(wall "$name")
    local ratio
    ratio=$(awk -v a="$w" -v b="$before_wall" 'BEGIN { printf "%.2fx", a / b }')
    local p="-"
    if [[ $name != before-f32 ]]; then
        p=$(compare before-f32 "$name")
    fi
    echo "| $build | $prec | $(text "$name") | $w | $(cpu "$name") | $ratio | $p |"
}
row before-f32 "before ($(git rev-parse --short "$BEFORE_REV"))" f32
row after-f32 "after ($after_rev)" f32
if [[ $bf16 == yes ]]; then
    row after-bf16 "after ($after_rev)" bf16
    echo
    echo "bf16 against f32 (after): held-out PSNR $(compare after-f32 after-bf16) dB"
else
    echo "| after | bf16 | skipped: this CPU lacks AVX512_BF16 | | | | |"
fi
echo
echo "logs, TFs and builds: $work (remove the worktree with: git worktree remove --force $before_tree)"
