#!/usr/bin/env bash
# t2tf's default optimization step against the PyTorch peer (../shared/peers/torch_t2tf.py: the
# same step in PyTorch on the CPU), in one run on one machine, the two taking turns.
#
# Both do the paper's default step on the 256³ aneurism: 3 random views at 224², CLIP ViT-B/32
# shapes with random weights, forward and input backward, 128 negatives, the renderer's forward
# and backward, f32, two threads. t2tf: `bench_optimize --no-grid --steps N` (per step: the
# loop's phases, without the initialization); the peer: its median step after its warm-up steps
# (it discards steps during which other processes used the CPU).
#
# Usage, from anywhere in the repository (needs ../shared next to the repository root):
#     PYTHON=VENV/bin/python scripts/bench_peer.sh [ROUNDS]
# VENV holds torch, transformers, numpy and pillow. ROUNDS (default 2) alternations of both.
# STEPS (default 30) sets t2tf's steps, PEER_STEPS (default 7, 2 of them warm-up) the peer's.
# The peer runs with tcmalloc preloaded where it is installed (libtcmalloc-minimal4; the peer's
# own notes: faster, same numerics). Run it on an idle machine.
set -euo pipefail

repo=$(git rev-parse --show-toplevel)
cd "$repo"
shared="$repo/../shared"
volume="$shared/data/volumes/aneurism_256x256x256_uint8.raw"
python=${PYTHON:-python3}
rounds=${1:-2}
steps=${STEPS:-30}
peer_steps=${PEER_STEPS:-7}
for f in "$volume" "$shared/peers/torch_t2tf.py"; do
    [[ -e "$f" ]] || { echo "bench_peer: $f is missing (../shared beside the repository)" >&2; exit 1; }
done
"$python" -c "import torch, transformers, numpy, PIL" 2>/dev/null || {
    echo "bench_peer: $python lacks torch, transformers, numpy or pillow (set PYTHON)" >&2
    exit 1
}

work=$(mktemp -d -t t2tf-bench-peer.XXXXXX)
trap 'rm -rf "$work"' EXIT
# The peer finds the CLIP config at its folder's ../shared/data/clip: give it that layout.
mkdir -p "$work/peers"
cp "$shared/peers/torch_t2tf.py" "$work/peers/"
ln -s "$(cd "$shared" && pwd)" "$work/shared"
preload=""
for lib in /usr/lib/x86_64-linux-gnu/libtcmalloc_minimal.so.4 /usr/lib64/libtcmalloc_minimal.so.4; do
    [[ -e "$lib" ]] && { preload=$lib; break; }
done

cargo build --release --quiet --features bench --example bench_optimize
bench="$repo/target/release/examples/bench_optimize"

echo "CPU: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) threads"
echo "peer: torch $("$python" -c 'import torch; print(torch.__version__)'), tcmalloc: $([[ -n $preload ]] && echo yes || echo no)"
echo
echo "| round | t2tf per step (s) | peer per step (s) | peer / t2tf |"
echo "|---|---|---|---|"
for r in $(seq 1 "$rounds"); do
    # t2tf: the per-step column of the phase rows after the initialization's.
    "$bench" --no-grid --steps "$steps" --threads 2 > "$work/t2tf.md" 2> "$work/t2tf.err" || {
        cat "$work/t2tf.err" >&2
        exit 1
    }
    ours=$(awk -F'|' '/^\| (render forward|CLIP image forward|CLIP image backward|render backward|other)/ {
        s += $4 } END { printf "%.3f", s }' "$work/t2tf.md")
    LD_PRELOAD="$preload" "$python" "$work/peers/torch_t2tf.py" --volume "$volume" \
        --steps "$peer_steps" --threads 2 --json "$work/peer.json" > "$work/peer.log" 2>&1 || {
        tail -20 "$work/peer.log" >&2
        exit 1
    }
    theirs=$("$python" -c "import json,sys; print('%.3f' % json.load(open(sys.argv[1]))['step median total'])" "$work/peer.json")
    ratio=$(awk -v a="$theirs" -v b="$ours" 'BEGIN { printf "%.2f", a / b }')
    echo "| $r | $ours | $theirs | **${ratio}×** |"
done
echo
echo "load average at the end: $(cut -d' ' -f1-3 /proc/loadavg)"
