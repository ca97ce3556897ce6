"""The README's Python examples type-check against the package's stubs (`_t2tf.pyi`) with
mypy: what the README shows is what a user's type checker accepts."""
import re

from conftest import REPO, require_module


def test_readme_python_examples_type_check(tmp_path):
    api = require_module("mypy.api", "T2TF_REQUIRE_MYPY")
    readme = (REPO / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, re.S)
    assert blocks, "the README has no Python example"
    checks = []
    for i, block in enumerate(blocks):
        path = tmp_path / f"readme_{i}.py"
        path.write_text(block)
        checks.append(str(path))
    # What the examples' results are, as mypy infers them: a single prompt gives a Result,
    # a list of prompts a list of them.
    probe = tmp_path / "probe.py"
    probe.write_text(
        "import numpy as np\nimport t2tf\n"
        "one: t2tf.Result = t2tf.optimize(np.zeros((4, 4, 4)), 'x')\n"
        "many: list[t2tf.Result] = t2tf.optimize('v.raw', ['a', 'b'])\n"
        "picture = t2tf.render('v.raw', 'tf.json')\n"
        "v = t2tf.Volume(np.zeros((4, 4, 4)), spacing=[1, 1, 2])\n")
    checks.append(str(probe))
    out, err, status = api.run(["--no-incremental", "--cache-dir", str(tmp_path / "cache"),
                                "--python-version", "3.9", *checks])
    assert status == 0, out + err
