"""t2tf.optimize: results, progress events, stopping (callback, exception, Ctrl-C), errors,
and Result.save."""
import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import t2tf
from conftest import MODEL, NEGHIP, QUICK, REPO, TOKENIZER


@pytest.fixture(scope="module")
def volume():
    return t2tf.read_volume(NEGHIP)


def test_a_run_gives_the_tf_report_and_preview(volume):
    events = []
    r = t2tf.optimize(volume, "a protein molecule", progress=events.append, **QUICK)
    assert (r.steps_run, r.interrupted) == (3, False)
    report = r.report
    assert report["steps_run"] == 3 and len(report["steps"]) == 3
    assert report["prompt"] == "a protein molecule"
    assert report["settings"]["seed"] == 3 and report["render"]["threads"] == 2
    assert r.preview.dtype == np.uint8 and r.preview.ndim == 3 and r.preview.shape[2] == 3
    tf = r.transfer_function
    assert tf.name.startswith("a-protein-molecule-")
    assert tf.range == pytest.approx(volume.range)
    assert set(r.camera) == {"position", "focal_point", "view_up", "view_angle"}
    kinds = [e["event"] for e in events]
    assert kinds[0] == "phase" and kinds.count("step") == 3
    steps = [e for e in events if e["event"] == "step"]
    assert [e["step"] for e in steps] == [1, 2, 3]
    # "total" is the run's step count, as in the library's events; the loss is "loss", its
    # parts under their own names.
    assert all(e["total"] == 3 for e in steps)
    for event, logged in zip(steps, report["steps"]):
        assert event["loss"] == logged["total"]
        assert event["loss"] != event["total"]
        for part in ("clip", "prior", "l1", "l2", "prompt_probability"):
            assert event[part] == logged[part]


def test_the_same_seed_gives_the_same_tf_with_a_loaded_model(volume):
    model = t2tf.load_model(MODEL, tokenizer=TOKENIZER)
    settings = dict(QUICK, model=model, tokenizer=None)
    a = t2tf.optimize(volume, "a protein molecule", **settings)
    b = t2tf.optimize(volume, "a protein molecule", **settings)
    np.testing.assert_array_equal(a.transfer_function.sample(300)[1],
                                  b.transfer_function.sample(300)[1])
    c = t2tf.optimize(volume, "a protein molecule", **dict(settings, seed=4))
    assert not np.array_equal(a.transfer_function.sample(300)[1],
                              c.transfer_function.sample(300)[1])


def test_returning_false_stops_after_that_step(volume):
    def stop_at_two(event):
        return not (event["event"] == "step" and event["step"] == 2)

    r = t2tf.optimize(volume, "a protein molecule", progress=stop_at_two,
                      **dict(QUICK, steps=50))
    assert (r.steps_run, r.interrupted) == (2, True)
    assert r.report["interrupted"] is True


def test_an_exception_in_the_callback_stops_the_run_and_is_raised(volume):
    seen = []

    def fail(event):
        seen.append(event)
        if event["event"] == "step":
            raise ValueError("enough")

    with pytest.raises(ValueError, match="enough"):
        t2tf.optimize(volume, "a protein molecule", progress=fail, **dict(QUICK, steps=50))
    assert [e["event"] for e in seen].count("step") == 1


def test_ctrl_c_stops_the_run_then_raises_keyboard_interrupt(tmp_path):
    # In a child process: SIGINT goes to the whole process, pytest included.
    script = textwrap.dedent("""
        import os, signal, threading, time, sys
        import t2tf
        steps = []
        def progress(event):
            if event["event"] == "step":
                steps.append(event["step"])
                if len(steps) == 1:  # Ctrl-C while the next steps compute
                    threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGINT)).start()
        t0 = time.time()
        try:
            t2tf.optimize(t2tf.read_volume(sys.argv[1]), "a protein molecule", model=sys.argv[2],
                          tokenizer=sys.argv[3], steps=100000, views=1, progress=progress)
        except KeyboardInterrupt:
            print("interrupted after", len(steps), "steps in", round(time.time() - t0, 2), "s")
    """)
    out = subprocess.run([sys.executable, "-c", script, str(NEGHIP), str(MODEL), str(TOKENIZER)],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    words = out.stdout.split()
    assert words[:2] == ["interrupted", "after"], out.stdout + out.stderr
    assert 1 <= int(words[2]) < 100000


@pytest.mark.parametrize("kwargs, error, words", [
    (dict(prompt="  "), t2tf.SettingsError, "prompt is empty"),
    (dict(prompt=None), t2tf.SettingsError, "prompt"),
    (dict(prompt="x", reference_image="a.png"), t2tf.SettingsError, "not both"),
    (dict(prompt="x", views=0), t2tf.SettingsError, "views"),
    # Sizes are bounded before anything is allocated (an allocation this large aborts).
    (dict(prompt="x", steps=10**12), t2tf.SettingsError, "steps.*at most 1000000"),
    # A negative count is a settings error, not Python's OverflowError.
    (dict(prompt="x", steps=-1), t2tf.SettingsError, "steps must be 0 or more, got -1"),
    (dict(prompt="x", views=-2), t2tf.SettingsError, "views must be 0 or more, got -2"),
    (dict(prompt="x", views=10**6), t2tf.SettingsError, "views.*at most 64"),
    (dict(prompt="x", prior_ab=-1.0), t2tf.SettingsError, "prior_ab"),
    (dict(prompt="x", threads=0), t2tf.SettingsError, "threads"),
    (dict(prompt="x", precision="f16"), t2tf.SettingsError, "precision"),
    (dict(prompt="x", up="w"), t2tf.SettingsError, "up"),
    (dict(prompt="x", model="no-such-folder/"), t2tf.ModelError, "no-such-folder"),
    (dict(prompt=None, reference_image="missing.png"), t2tf.SettingsError, "missing.png"),
    (dict(prompt="x", max_memory="1K"), t2tf.BudgetError, "only 1.0 KiB is available"),
])
def test_errors_are_t2tf_exceptions(volume, kwargs, error, words):
    settings = dict(QUICK)
    settings.update(kwargs)
    prompt = settings.pop("prompt")
    with pytest.raises(error, match=words):
        t2tf.optimize(volume, prompt, **settings)


@pytest.mark.parametrize("kwargs, kind, option", [
    (dict(prompt="  "), "empty_prompt", "prompt"),
    (dict(prompt="x", views=0), "invalid_option", "views"),
    (dict(prompt="x", prior_ab=-1.0), "invalid_option", "prior_ab"),
    (dict(prompt="x", threads=0), "invalid_option", "threads"),
    (dict(prompt="x", model="no-such-folder/"), "invalid_option", "model"),
    (dict(prompt="x", max_memory="1K"), "memory", None),
    # Raised by the module itself: its class's kind.
    (dict(prompt=None), "invalid_option", None),
])
def test_errors_carry_their_kind_and_option(volume, kwargs, kind, option):
    """Every t2tf exception says what kind of problem it is and which keyword it is about,
    so a caller (the ParaView plugin) words its own advice without reading the message."""
    settings = dict(QUICK)
    settings.update(kwargs)
    prompt = settings.pop("prompt")
    with pytest.raises(t2tf.Error) as raised:
        t2tf.optimize(volume, prompt, **settings)
    assert (raised.value.kind, raised.value.option) == (kind, option), str(raised.value)
    # Python's advice names keywords, never the command line's flags.
    assert "--" not in str(raised.value), str(raised.value)


def test_memory_advice_names_the_keyword(volume):
    with pytest.raises(t2tf.BudgetError) as raised:
        t2tf.optimize(volume, "x", max_memory="1K", **QUICK)
    assert 'max_memory="16G"' in str(raised.value), str(raised.value)


def test_unknown_keywords_are_type_errors(volume):
    with pytest.raises(TypeError, match="stpes"):
        t2tf.optimize(volume, "x", stpes=3)


def test_save_writes_the_clis_output_set(volume, tmp_path):
    r = t2tf.optimize(volume, "a protein molecule", **QUICK)
    report = r.save(tmp_path / "Neghip TF")
    out = tmp_path / "Neghip TF"
    # The CLI's rule: the TF files are named after the folder.
    assert report["outputs"][:3] == ["neghip-tf.json", "neghip-tf.xml", "neghip-tf.ct"]
    assert "neghip-tf_paraview.py" in report["outputs"]  # a file volume gets the scripts
    for name in report["outputs"]:
        assert (out / name).is_file(), name
    on_disk = json.loads((out / "report.json").read_text())
    assert on_disk["steps_run"] == 3 and on_disk["outputs"] == report["outputs"]
    saved = t2tf.TransferFunction.load(out / "neghip-tf.json")
    np.testing.assert_allclose(saved.sample(200)[1],
                               r.transfer_function.sample(200)[1], atol=1e-12)
    assert r.save(tmp_path / "again", name="bone")["outputs"][0] == "bone.json"


def test_an_array_volume_saves_without_scripts(neghip, tmp_path):
    r = t2tf.optimize(t2tf.Volume(neghip), "a protein molecule", **QUICK)
    outputs = r.save(tmp_path / "out")["outputs"]
    assert not any(name.endswith(".py") for name in outputs)
    assert r.report["volume"]["path"] == "(in memory)"


def test_save_errors_are_output_errors(volume, tmp_path):
    r = t2tf.optimize(volume, "a protein molecule", **dict(QUICK, steps=0))
    (tmp_path / "file").write_text("")
    with pytest.raises(t2tf.OutputError, match="not a folder"):
        r.save(tmp_path / "file")
    with pytest.raises(t2tf.SettingsError, match="plain file name"):
        r.save(tmp_path / "out", name="a/b")


@pytest.mark.skipif(sys.platform == "win32", reason="RLIMIT_FSIZE is POSIX")
def test_a_failed_write_is_an_output_error_and_leaves_nothing(volume, tmp_path):
    """A full disk fails `write` as a file-size limit does (EFBIG instead of ENOSPC)."""
    import resource
    import signal

    r = t2tf.optimize(volume, "a protein molecule", **dict(QUICK, steps=0))
    out = tmp_path / "out"
    old_limit = resource.getrlimit(resource.RLIMIT_FSIZE)
    old_handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (16 << 10, old_limit[1]))
    try:
        with pytest.raises(t2tf.OutputError, match="File too large"):
            r.save(out)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, old_limit)
        signal.signal(signal.SIGXFSZ, old_handler)
    assert not out.exists(), list(out.iterdir())


def test_names_follow_the_clis_rule_for_any_prompt(volume, tmp_path):
    r = t2tf.optimize(volume, "-x ray of a head", **dict(QUICK, steps=0))
    assert r.transfer_function.name.startswith("x-ray-of-a-head-")
    assert r.save(tmp_path / "-out")["outputs"][0] == "out.json"


def test_a_list_of_prompts_gives_each_the_tf_of_its_own_run(volume):
    prompts = ["a red molecule", "a blue cloud"]
    batch = t2tf.optimize(volume, prompts, **QUICK)
    assert isinstance(batch, list) and len(batch) == 2
    for prompt, result in zip(prompts, batch):
        alone = t2tf.optimize(volume, prompt, **QUICK)
        assert result.report["prompt"] == prompt
        a = alone.transfer_function.sample(256)[1]
        b = result.transfer_function.sample(256)[1]
        assert np.array_equal(a, b)


def test_init_and_lock_refine_a_tf_and_keep_the_locked_range(volume):
    first = t2tf.optimize(volume, "a red molecule", **QUICK)
    # steps=0 from a TransferFunction: the start itself comes back.
    start = t2tf.optimize(volume, "a blue cloud", init=first.transfer_function,
                          **dict(QUICK, steps=0))
    values, want = first.transfer_function.sample(1024)
    _, got = start.transfer_function.sample(1024)
    assert np.abs(got - want).max() <= 2e-3
    # A refine with a lock: the range stays, the rest moves.
    refined = t2tf.optimize(volume, "a blue cloud", init=first.transfer_function,
                            lock=[(40, 120)], **dict(QUICK, steps=6))
    _, after = refined.transfer_function.sample(1024)
    inside = (values >= 40) & (values <= 120)
    assert np.abs(after[inside] - want[inside]).max() <= 2e-3
    assert np.abs(after[~inside] - want[~inside]).max() > 1e-3
    assert refined.report["locks"] == [[40.0, 120.0]]


@pytest.mark.parametrize("kwargs, words", [
    (dict(lock=[(120, 40)]), "MIN < MAX"),
    (dict(lock=[(0, 300)]), "outside the data range"),
    (dict(init="no-such-preset.json"), "no-such-preset.json"),
    (dict(preset="Cividis"), "give init too"),
])
def test_bad_starts_are_settings_or_format_errors(volume, kwargs, words):
    with pytest.raises(t2tf.Error, match=words):
        t2tf.optimize(volume, "x", **QUICK, **kwargs)


def test_a_volume_is_a_volume_an_array_or_a_path(neghip):
    """What the README says volumes are: arrays or files, as well as `Volume`s; each gives the
    TF of the same data."""
    runs = [t2tf.optimize(v, "a protein molecule", **dict(QUICK, steps=1))
            for v in (t2tf.read_volume(NEGHIP), neghip, str(NEGHIP), NEGHIP)]
    first = runs[0].transfer_function.sample(64)[1]
    for r in runs[1:]:
        np.testing.assert_array_equal(r.transfer_function.sample(64)[1], first)
    with pytest.raises(t2tf.VolumeError, match="3-D array"):
        t2tf.optimize(np.zeros((4, 4)), "x", **QUICK)
    assert repr(runs[0]).startswith("Result(steps_run=1, interrupted=False, ")


def test_the_report_holds_the_call_and_repeats_the_run(tmp_path, monkeypatch):
    """report.json's python_call (keywords as given, paths absolute) runs the same TF again
    from another folder."""
    monkeypatch.chdir(REPO)
    settings = dict(QUICK, model=str(MODEL.relative_to(REPO)), up="-y", control_points=10,
                    step_size=0.8)
    r = t2tf.optimize(str(NEGHIP), "a protein molecule", **settings)
    call = r.report["python_call"]
    assert call["up"] == "-y" and call["steps"] == 3 and call["control_points"] == 10
    assert call["model"] == str(MODEL) and call["tokenizer"] == str(TOKENIZER)
    assert call["volume"] == str(NEGHIP)
    assert r.report["cwd"] == str(REPO)
    assert r.report["render"]["up"] == "-y"
    assert r.report["model"]["folder"] == str(MODEL)
    monkeypatch.chdir(tmp_path)
    keywords = {k: v for k, v in call.items() if k not in ("volume", "prompt") and v is not None}
    again = t2tf.optimize(call["volume"], call["prompt"], **keywords)
    np.testing.assert_array_equal(r.transfer_function.rgb_points,
                                  again.transfer_function.rgb_points)
    np.testing.assert_array_equal(r.transfer_function.opacity_points,
                                  again.transfer_function.opacity_points)
    # The up axis the report records is the one that made the TF.
    other = t2tf.optimize(call["volume"], call["prompt"], **dict(keywords, up="z"))
    assert not np.array_equal(r.transfer_function.opacity_points,
                              other.transfer_function.opacity_points)


def test_steps_0_from_a_tf_needs_no_model(tmp_path, volume, monkeypatch):
    # Nothing here may reach the Hub: a model that is looked up fails at once.
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    start = t2tf.optimize(volume, "a protein molecule", **QUICK)
    path = tmp_path / "start.json"
    start.transfer_function.save(path)
    r = t2tf.optimize(volume, "a protein molecule", steps=0, init=str(path),
                      model="no-such-org/no-such-model", threads=2)
    assert r.report["model"] is None and r.steps_run == 0
    assert r.report["init_file"]["path"] == str(path)
    import hashlib
    assert r.report["init_file"]["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    # A loaded model given is used: the same TF and preview with it.
    model = t2tf.load_model(str(MODEL), tokenizer=str(TOKENIZER))
    with_model = t2tf.optimize(volume, "a protein molecule", steps=0, init=str(path),
                               model=model, threads=2)
    assert with_model.report["model"]["id"] == str(MODEL)
    np.testing.assert_array_equal(r.preview, with_model.preview)
    np.testing.assert_array_equal(r.transfer_function.opacity_points,
                                  with_model.transfer_function.opacity_points)
    # Without a start the paper's initialization is measured at CLIP's size: it loads.
    with pytest.raises(t2tf.ModelError):
        t2tf.optimize(volume, "a protein molecule", steps=0, model="no-such-org/no-such-model",
                      threads=2)


def test_offline_without_the_model_names_the_keyword(tmp_path):
    """The README's example passes no `model=`: offline, the error says what to pass."""
    env = dict(os.environ, HF_HUB_OFFLINE="1", HF_HUB_CACHE=str(tmp_path / "hub"),
               XDG_CACHE_HOME=str(tmp_path / "cache"))
    code = ("import json, numpy as np, t2tf\n"
            "try:\n"
            "    t2tf.optimize(np.zeros((8, 8, 8), np.float32), 'a skull', steps=1)\n"
            "except t2tf.ModelError as e:\n"
            "    print(json.dumps([str(e), e.kind, e.option]))\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    said, kind, option = json.loads(out.stdout)
    assert (kind, option) == ("model_unavailable", "model"), out.stdout
    assert "offline mode is on" in said, said
    assert "model=DIR" in said and "`model`" not in said, said
    assert "t2tf model fetch openai/clip-vit-base-patch32" in said, said
    # No path of the checkout the wheel was built from: installed users have none.
    for path in (MODEL, TOKENIZER, REPO):
        assert str(path.resolve()) not in said, said
