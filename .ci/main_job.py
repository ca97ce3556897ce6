#!/usr/bin/env python3
"""The main job end to end with a t2tf built for another platform, against this machine's.

    python3 .ci/main_job.py --label windows --reference target/release/t2tf \
        -- wine target/x86_64-pc-windows-gnu/release/t2tf.exe

Runs `info`, `convert`, `render` and a short `optimize` with the tiny test model twice, once
with the reference t2tf (this machine's) and once with the command after `--` (under wine or
qemu-user), and checks that the second run's outputs are all there and agree with the first:
the same volume summary, the same converted colour table, the same picture within 2/255 per
channel, every file of the output folder, per-step losses within 1e-5 and a transfer
function within the spread of this machine's own CLIP engines (TF_TOL). With `--windows-paths` the second
run's output folder is given as a Windows path (drive letter, backslashes, a space) and the
pvpython script it writes must name the volume as Windows opens it.

Timings under emulation are not timings: this script checks results only.
"""

import argparse
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import zlib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
VOLUME = os.path.join(ROOT, "..", "shared", "data", "volumes", "neghip_64x64x64_uint8.raw")
PRESET = os.path.join(ROOT, "tests", "fixtures", "paraview", "colorspace_Lab.json")
MODEL = os.path.join(ROOT, "tests", "fixtures", "clip", "quick_gelu")
TOKENIZER = os.path.join(ROOT, "..", "shared", "data", "clip", "tokenizer.json")
# Colour and opacity of the two builds' TFs, sampled over the data range: two SGD steps at
# learning rate 10 carry the CLIP kernels' last bits into the TF. This machine's own engines
# differ by up to this much on this run (tests/optimize/optimize_pipeline.rs,
# the_engines_agree_on_the_cross_platform_run); the losses, before the steps amplify
# anything, must agree far closer (LOSS_TOL, relative).
TF_TOL = 2e-2
LOSS_TOL = 1e-5
OUTPUTS = ["report.json", "preview.png", "tf.png"]
OUTPUT_SUFFIXES = [".json", ".xml", ".ct", "_paraview.py", "_visit.py"]


def fail(label, what):
    print(f"main job [{label}]: FAILED: {what}", file=sys.stderr)
    sys.exit(1)


def run(label, cmd, args, cwd):
    proc = subprocess.run(cmd + args, cwd=cwd, capture_output=True, text=True,
                          env=dict(os.environ, WINEDEBUG="-all"))
    if proc.returncode != 0:
        fail(label, f"`t2tf {' '.join(args)}` exited {proc.returncode}: {proc.stderr.strip()[-2000:]}")
    return proc.stdout


def png_pixels(path):
    """Width, height and the RGB(A) bytes of an 8-bit non-interlaced PNG."""
    data = open(path, "rb").read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError(f"{path}: not a PNG")
    pos, idat, width, height, ctype = 8, b"", 0, 0, 0
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            width, height, depth, ctype = struct.unpack(">IIBB", body[:10])
            if depth != 8:
                raise ValueError(f"{path}: bit depth {depth}")
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    channels = {2: 3, 6: 4}[ctype]
    raw = zlib.decompress(idat)
    stride = width * channels
    out, prev = bytearray(), bytearray(stride)
    for row in range(height):
        f = raw[row * (stride + 1)]
        line = bytearray(raw[row * (stride + 1) + 1:(row + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - channels] if i >= channels else 0
            b = prev[i]
            c = prev[i - channels] if i >= channels else 0
            if f == 1:
                line[i] = (line[i] + a) & 255
            elif f == 2:
                line[i] = (line[i] + b) & 255
            elif f == 3:
                line[i] = (line[i] + (a + b) // 2) & 255
            elif f == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                line[i] = (line[i] + pred) & 255
        out += line
        prev = line
    return width, height, bytes(out)


def same_picture(label, a, b):
    wa, ha, pa = png_pixels(a)
    wb, hb, pb = png_pixels(b)
    if (wa, ha) != (wb, hb):
        fail(label, f"{b}: {wb}x{hb} pixels, the reference has {wa}x{ha}")
    worst = max(abs(x - y) for x, y in zip(pa, pb))
    if worst > 2:
        fail(label, f"{b}: differs from the reference by up to {worst}/255")
    if max(pb) == min(pb):
        fail(label, f"{b}: one flat colour")


def tf_points(path):
    return json.load(open(path))[0]


def sampled(points, channels, lo, hi, n=2048):
    """A piecewise-linear TF's points (x, then `channels` values; opacity points also carry
    midpoint and sharpness, which t2tf writes as 0.5 and 0: linear) at n data values."""
    stride = 4
    xs = points[0::stride]
    out = []
    for k in range(n):
        x = lo + (hi - lo) * k / (n - 1)
        j = 0
        while j + 1 < len(xs) - 1 and xs[j + 1] < x:
            j += 1
        x0, x1 = xs[j], xs[min(j + 1, len(xs) - 1)]
        t = 0.0 if x1 == x0 else min(1.0, max(0.0, (x - x0) / (x1 - x0)))
        for c in range(1, channels + 1):
            v0 = points[j * stride + c]
            v1 = points[min(j + 1, len(xs) - 1) * stride + c]
            out.append(v0 + t * (v1 - v0))
    return out


def close(label, what, a, b, tol):
    if len(a) != len(b):
        fail(label, f"{what}: {len(b)} values, the reference has {len(a)}")
    worst = max((abs(x - y) for x, y in zip(a, b)), default=0.0)
    if not worst <= tol:
        fail(label, f"{what}: differs from the reference by {worst:g} (> {tol:g})")
    return worst


def main_job(label, cmd, work, out_arg, out_dir):
    """Every command of the main job with `cmd`; returns where its files are."""
    info = json.loads(run(label, cmd, ["info", VOLUME, "--json"], work))
    if info.get("dims") != [64, 64, 64]:
        fail(label, f"info: dims {info.get('dims')}")
    run(label, cmd, ["convert", PRESET, os.path.join(work, "lab.ct")], work)
    run(label, cmd, ["render", VOLUME, "--tf", PRESET, "--size", "96",
                     "--out", os.path.join(work, "render.png")], work)
    negatives = os.path.join(work, "negatives.txt")
    with open(negatives, "w") as f:
        f.write("a blank image\na photo of a cat\na red car\na city at night\n")
    run(label, cmd, ["optimize", VOLUME, "--prompt", "a red molecule", "--model", MODEL,
                     "--tokenizer", TOKENIZER, "--negatives-file", negatives, "--steps", "2",
                     "--views", "1", "--negatives-per-step", "3", "--render-size", "64",
                     "--out", out_arg, "--name", "tf", "--seed", "7",
                     # f32 on both sides: `auto` picks per CPU (bf16 on an x86 with a bf16
                     # kernel, f32 under qemu's aarch64), and this compares the platforms.
                     "--precision", "f32"], work)
    for name in OUTPUTS + ["tf" + s for s in OUTPUT_SUFFIXES]:
        path = os.path.join(out_dir, name)
        if not os.path.isfile(path) or os.path.getsize(path) == 0:
            fail(label, f"optimize did not write {name}")
    leftovers = [n for n in os.listdir(out_dir) if n.startswith(".t2tf")]
    if leftovers:
        fail(label, f"optimize left {leftovers} in its output folder")
    return info


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--label", required=True)
    ap.add_argument("--reference", required=True, help="this machine's t2tf")
    ap.add_argument("--windows-paths", action="store_true")
    ap.add_argument("cmd", nargs="+", help="the t2tf to check, with its runner")
    a = ap.parse_args()
    label = a.label
    # The commands run in folders of their own: paths given relative to here made absolute.
    a.reference = os.path.abspath(a.reference)
    a.cmd = [os.path.abspath(c) if os.path.exists(c) else c for c in a.cmd]
    base = tempfile.mkdtemp(prefix="t2tf-main-job-")
    try:
        ref, new = os.path.join(base, "ref"), os.path.join(base, "new dir")
        os.makedirs(ref)
        os.makedirs(new)
        ref_out = os.path.join(ref, "out")
        info_ref = main_job(label, [a.reference], ref, ref_out, ref_out)
        new_out = os.path.join(new, "out folder")
        # Wine maps drive Z: to the root of this machine.
        out_arg = ("Z:" + new_out.replace("/", "\\")) if a.windows_paths else new_out
        info_new = main_job(label, a.cmd, new, out_arg, new_out)

        keys = ["dims", "dtype", "spacing", "origin", "range", "histogram", "non_finite", "pyramid"]
        for key in keys:
            if info_new.get(key) != info_ref.get(key):
                fail(label, f"info --json: {key} differs from the reference")
        if open(os.path.join(ref, "lab.ct")).read() != open(os.path.join(new, "lab.ct")).read():
            fail(label, "convert wrote a different .ct")
        same_picture(label, os.path.join(ref, "render.png"), os.path.join(new, "render.png"))
        # The curves, sampled over the data range: the exported points are simplified within
        # a tolerance, so two builds whose curves agree may keep different points.
        lo, hi = info_ref["range"]
        worst = 0.0
        for key, channels in (("RGBPoints", 3), ("Points", 1)):
            curve_a = sampled(tf_points(os.path.join(ref_out, "tf.json"))[key], channels, lo, hi)
            curve_b = sampled(tf_points(os.path.join(new_out, "tf.json"))[key], channels, lo, hi)
            worst = max(worst, close(label, key, curve_a, curve_b, TF_TOL))
        losses = [[s["total"] for s in json.load(open(os.path.join(d, "report.json")))["steps"]]
                  for d in (ref_out, new_out)]
        for step, (a_loss, b_loss) in enumerate(zip(*losses)):
            if not abs(a_loss - b_loss) <= LOSS_TOL * abs(a_loss):
                fail(label, f"step {step}: loss {b_loss!r}, the reference's {a_loss!r}")
        script = open(os.path.join(new_out, "tf_paraview.py")).read()
        compile(script, "tf_paraview.py", "exec")
        if a.windows_paths and "Z:\\\\" not in script and "Z:/" not in script and "Z:\\" not in script:
            fail(label, "the pvpython script does not name the volume by its Windows path")
        report = json.load(open(os.path.join(new_out, "report.json")))
        machine = report.get("machine", {})
        print(f"main job [{label}]: info, convert, render and optimize agree with the reference "
              f"(losses within {LOSS_TOL:g}, TF within {worst:.1e}); ran on {machine.get('os')}, CPU "
              f"{machine.get('cpu_model')!r}, CLIP: {report.get('render', {}).get('clip_engine', '?')}")
    finally:
        shutil.rmtree(base, ignore_errors=True)


if __name__ == "__main__":
    main()
