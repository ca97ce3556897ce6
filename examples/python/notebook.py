# %% [markdown]
# # t2tf in a notebook
#
# Cells for Jupyter (or VS Code's `# %%` cells); it also runs as a script:
# `python examples/python/notebook.py`. Offline it uses the tiny test model in
# tests/fixtures; set `MODEL = None` (and `TOKENIZER = None`) for the real CLIP model.

# %%
from pathlib import Path

import numpy as np

import t2tf

try:
    REPO = Path(__file__).resolve().parents[2]
except NameError:  # in a notebook opened from examples/python
    REPO = Path.cwd().resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"
MODEL = REPO / "tests" / "fixtures" / "clip" / "quick_gelu"
TOKENIZER = SHARED / "clip" / "tokenizer.json"

# %% Any 3-D NumPy array indexed [z, y, x] is a volume; here a raw file read with NumPy.
values = np.fromfile(SHARED / "volumes" / "neghip_64x64x64_uint8.raw", dtype=np.uint8)
volume = t2tf.Volume(values.reshape(64, 64, 64))
volume

# %% Optimize, with a line of progress every 10 steps (returning False would stop the run).


def progress(event):
    if event["event"] == "step" and event["step"] % 10 == 0:
        print("step %d/%d  loss %.3f" % (event["step"], event["steps"], event["loss"]))


model = t2tf.load_model(MODEL, tokenizer=TOKENIZER)  # loaded once, reused by later runs
result = t2tf.optimize(volume, "a protein molecule", steps=30, model=model, progress=progress)
result

# %% The transfer function in data units, sampled for plotting.
tf = result.transfer_function
x, rgba = tf.sample(256)
print(tf, "opacity peaks at", x[np.argmax(rgba[:, 3])])

# %% A picture: matplotlib shows it inline in a notebook; as a script it is saved.
picture = t2tf.render(volume, tf, yaw=45, size=256)
try:
    import matplotlib

    if "__file__" in globals():
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(8, 4))
    a.imshow(picture)
    a.axis("off")
    b.imshow(result.preview)
    b.axis("off")
    fig.savefig("notebook.png")
except ImportError:
    print("matplotlib not installed: the picture is", picture.shape, picture.dtype)

# %% The files `t2tf optimize` writes (presets for ParaView and VisIt, report.json, ...).
report = result.save("notebook-tf")
print("wrote", ", ".join(report["outputs"]))
