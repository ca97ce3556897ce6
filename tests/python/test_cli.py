"""The wheel's `t2tf` command, and the same numbers from Python as from it."""
import subprocess
import sys

import t2tf
from conftest import MODEL, NEGHIP, QUICK, TOKENIZER, t2tf_command


def test_the_command_is_the_rust_cli():
    out = subprocess.run([t2tf_command(), "--version"], capture_output=True, text=True)
    assert (out.returncode, out.stdout.strip()) == (0, "t2tf " + t2tf.__version__)
    usage = subprocess.run([t2tf_command(), "optimize", "--stpes", "3"],
                           capture_output=True, text=True)
    assert usage.returncode == 2 and "--stpes" in usage.stderr
    failed = subprocess.run([sys.executable, "-m", "t2tf", "info", "no-such.raw"],
                            capture_output=True, text=True)
    assert failed.returncode == 1
    assert failed.stderr.startswith("t2tf: error:") and "no-such.raw" in failed.stderr
    # `python -m t2tf` names the program as the command does, not `__main__.py`.
    helped = subprocess.run([sys.executable, "-m", "t2tf", "--help"], capture_output=True,
                            text=True)
    assert helped.returncode == 0 and "Usage: t2tf <COMMAND>" in helped.stdout, helped.stdout


def test_optimize_writes_the_clis_tf_bit_for_bit(tmp_path):
    settings = dict(QUICK, steps=6, views=2, negatives=["a blank image", "a cat"],
                    l1=1e-4, control_points=12, precision="f32")
    flags = ["--model", str(MODEL), "--tokenizer", str(TOKENIZER), "--steps", "6",
             "--views", "2", "--seed", "3", "--negatives-per-step", "8", "--threads", "2",
             "--negative", "a blank image", "--negative", "a cat", "--l1", "1e-4",
             "--control-points", "12",
             # f32 on both sides: bit for bit whatever auto would pick here.
             "--precision", "f32"]
    cli_out = tmp_path / "cli"
    subprocess.run([t2tf_command(), "optimize", str(NEGHIP), "--prompt", "a protein molecule",
                    "--out", str(cli_out), "--progress", "json"] + flags,
                   check=True, capture_output=True)
    py_out = tmp_path / "py"
    r = t2tf.optimize(t2tf.read_volume(NEGHIP), "a protein molecule", **settings)
    r.save(py_out, name="cli")
    for ext in ("json", "xml", "ct"):
        name = "cli." + ext
        assert (py_out / name).read_bytes() == (cli_out / name).read_bytes(), name
