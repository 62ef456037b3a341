"""The public API: every name typed in the stubs with a docstring, the stubs' signatures and
defaults those of the compiled functions, and the README's example."""

import ast
import inspect
import pathlib

import flowfilter

STUBS = pathlib.Path(flowfilter.__file__).with_name("_flowfilter.pyi")


def stub_definitions():
    tree = ast.parse(STUBS.read_text())
    names = {}
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names[node.name] = node
        elif isinstance(node, ast.AnnAssign):
            names[node.target.id] = node
    return names


def test_every_public_name_is_in_the_stubs_with_a_docstring():
    stubs = stub_definitions()
    missing = [n for n in flowfilter.__all__ if n not in stubs]
    assert not missing, missing
    for name in flowfilter.__all__:
        obj = getattr(flowfilter, name)
        if callable(obj) and not isinstance(obj, type):
            assert obj.__doc__ and len(obj.__doc__) > 40, name
            assert ast.get_docstring(stubs[name]), name
        if isinstance(obj, type) and not issubclass(obj, BaseException):
            assert obj.__doc__, name
            for member, node in ((n.name, n) for n in stubs[name].body if isinstance(n, ast.FunctionDef)):
                if member.startswith("__"):
                    continue
                assert hasattr(obj, member), f"{name}.{member}"
                assert ast.get_docstring(node), f"{name}.{member}"


def test_stub_signatures_are_the_runtime_signatures():
    stubs = stub_definitions()
    for name in flowfilter.__all__:
        obj = getattr(flowfilter, name)
        if not callable(obj) or isinstance(obj, type):
            continue
        runtime = inspect.signature(obj)
        node = stubs[name]
        args = node.args
        stub_names = [a.arg for a in args.args] + ([args.vararg.arg] if args.vararg else []) + [a.arg for a in args.kwonlyargs]
        stub_names += [args.kwarg.arg] if args.kwarg else []
        assert stub_names == list(runtime.parameters), f"{name}: stub {stub_names}, runtime {list(runtime.parameters)}"
        positional_defaults = dict(zip([a.arg for a in args.args][len(args.args) - len(args.defaults):], args.defaults))
        keyword_defaults = {a.arg: d for a, d in zip(args.kwonlyargs, args.kw_defaults) if d is not None}
        for param, default in {**positional_defaults, **keyword_defaults}.items():
            assert ast.literal_eval(default) == runtime.parameters[param].default, f"{name}({param}=...)"


def test_defaults_follow_the_configuration():
    assert inspect.signature(flowfilter.estimate_normals).parameters["k"].default == flowfilter.DEFAULT_KNN
    assert inspect.signature(flowfilter.register).parameters["method"].default == "filterreg-pt2pt"
    assert inspect.signature(flowfilter.estimate).parameters["method"].default == flowfilter.default_config()["method"]


def test_exceptions_are_in_the_package():
    assert flowfilter.Error.__module__ == "flowfilter" and issubclass(flowfilter.Error, Exception)
    assert flowfilter.__version__.count(".") == 2


def python_blocks(path):
    text = path.read_text()
    blocks = text.split("```python\n")[1:]
    return [b.split("```")[0] for b in blocks]


def test_readme_examples_run(monkeypatch, capsys):
    """The repository README's Python example and the package README's first one."""
    root = pathlib.Path(__file__).resolve().parents[3]
    monkeypatch.chdir(root)
    for readme in [root / "README.md", root / "crates" / "flowfilter-py" / "README.md"]:
        code = python_blocks(readme)[0]
        namespace = {}
        exec(compile(code, str(readme), "exec"), namespace)
        assert namespace["icp"].fitness > 0.99 if "icp" in namespace else namespace["result"].fitness > 0.99
        assert namespace["fr"].converged
    assert "[[" in capsys.readouterr().out
