"""The compiled module documents itself: help() shows every parameter of every public
function and method with its real default (never `...`), and the type stubs (`_t2tf.pyi`)
agree with the module on every parameter and default."""
import ast
import inspect
import re
import subprocess

import pytest

import t2tf
from t2tf import _t2tf
from conftest import REPO, t2tf_command

STUBS = REPO / "python" / "t2tf" / "_t2tf.pyi"


def public_callables():
    """(name, callable) of every public function, constructor and method of the module
    (`cli_main` included: the `t2tf` script calls it)."""
    found = [("cli_main", _t2tf.cli_main)]
    for name in t2tf.__all__:
        obj = getattr(t2tf, name)
        if inspect.isclass(obj):
            if issubclass(obj, BaseException):
                continue
            if obj.__text_signature__ is not None:
                found.append((name, obj))
            for attr, member in vars(obj).items():
                if attr.startswith("_") or isinstance(member, property):
                    continue
                if callable(getattr(obj, attr)) and not inspect.isdatadescriptor(member):
                    found.append((f"{name}.{attr}", getattr(obj, attr)))
        elif callable(obj):
            found.append((name, obj))
    return found


def parameters(obj):
    return [p for p in inspect.signature(obj).parameters.values()
            if p.name not in ("self", "$self")]


@pytest.mark.parametrize("name,obj", public_callables(), ids=lambda v: v if isinstance(v, str) else "")
def test_signature_has_real_defaults_and_the_doc_names_each_parameter(name, obj):
    params = parameters(obj)
    for p in params:
        assert p.default is not Ellipsis, f"{name}: {p.name}=..."
    doc = inspect.getdoc(obj) or ""
    assert len(doc.splitlines()) >= 2 or len(params) <= 1, f"{name}: {doc!r}"
    for p in params:
        assert re.search(rf"\b{p.name}\b", doc), f"{name}'s doc does not mention {p.name}"


def test_help_of_optimize_shows_parameters_and_defaults():
    text = "\n".join(line.rstrip() for line in (inspect.getdoc(t2tf.optimize) or "").split("\n"))
    sig = str(inspect.signature(t2tf.optimize))
    assert "steps=300" in sig and "up='z'" in sig and "caption_cache=True" in sig, sig
    assert "Ellipsis" not in sig and "..." not in sig, sig
    assert "    steps: SGD steps" in text


def stub_functions():
    """Each function of the stubs by name (the first of overloads), and each class's
    methods as CLASS.METHOD (`__init__` as the class)."""
    tree = ast.parse(STUBS.read_text())
    out = {}
    for node in tree.body:
        if isinstance(node, ast.FunctionDef):
            out.setdefault(node.name, node)
        elif isinstance(node, ast.ClassDef):
            for item in node.body:
                if isinstance(item, ast.FunctionDef):
                    if any(isinstance(d, ast.Name) and d.id == "property"
                           for d in item.decorator_list):
                        continue
                    key = node.name if item.name == "__init__" else f"{node.name}.{item.name}"
                    out.setdefault(key, item)
    return out


def stub_parameters(fn):
    """(name, kind, default) of a stub's parameters, self left out; keyword-only ones
    sorted (their order does not matter to a caller)."""
    a = fn.args
    positional = a.posonlyargs + a.args
    defaults = [None] * (len(positional) - len(a.defaults)) + list(a.defaults)
    empty = inspect.Parameter.empty
    value = lambda node: empty if node is None else eval(compile(ast.Expression(node), "", "eval"))
    out = [(arg.arg, "positional", value(d)) for arg, d in zip(positional, defaults)
           if arg.arg != "self"]
    kw = [(arg.arg, "keyword", value(d)) for arg, d in zip(a.kwonlyargs, a.kw_defaults)]
    return out + sorted(kw)


def runtime_parameters(obj):
    out, kw = [], []
    for p in parameters(obj):
        if p.kind == p.KEYWORD_ONLY:
            kw.append((p.name, "keyword", p.default))
        else:
            out.append((p.name, "positional", p.default))
    return out + sorted(kw)


def test_the_stubs_agree_with_the_module():
    stubs = stub_functions()
    for name, obj in public_callables():
        assert name in stubs, f"{name} is not in _t2tf.pyi"
        assert stub_parameters(stubs[name]) == runtime_parameters(obj), name


def test_optimize_defaults_are_the_cli_flags_defaults():
    """The text signature is written out by hand: its numbers are the command's defaults."""
    help_text = subprocess.run([t2tf_command(), "optimize", "--help"], capture_output=True,
                               text=True, check=True).stdout
    sig = inspect.signature(t2tf.optimize).parameters
    for keyword in ("steps", "views", "seed", "lr", "momentum", "prior_weight", "prior_ab",
                    "prior_start", "l1", "l2", "control_points", "negatives_per_step",
                    "up", "precision"):
        flag = "--" + keyword.replace("_", "-")
        m = re.search(rf"{flag} <[^>]+>\n(?:.*\n)*?.*\[default: ([^\]]+)\]", help_text)
        assert m, f"{flag} has no default in --help"
        default = sig[keyword].default
        if isinstance(default, str):
            assert default == m.group(1), keyword
        else:
            assert default == pytest.approx(float(m.group(1)), rel=0, abs=0), keyword
