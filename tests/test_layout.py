"""The shape of the package: no import cycles (imports inside functions included), nothing
installed at the top level but ``wavlight``, options declared once and the docs' option tables
generated from that declaration."""
from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _modules() -> dict:
    """module name -> source file, for wavlight/ and the folders installed inside it (pyproject)."""
    with open(ROOT / "pyproject.toml", "rb") as fh:
        package_dir = tomllib.load(fh)["tool"]["setuptools"].get("package-dir", {})
    roots = {"wavlight": ROOT / "wavlight", **{name: ROOT / folder for name, folder in package_dir.items()}}
    mods = {}
    for name, folder in roots.items():
        for path in folder.rglob("*.py"):
            rel = path.relative_to(folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            mods[".".join([name, *parts])] = path
    return mods


def _imports(name: str, path: Path, mods: dict) -> set:
    """The project modules that ``name`` imports anywhere in its file (functions included)."""
    is_package = path.name == "__init__.py"
    package = name if is_package else name.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            # "from p import m" imports the module p.m where there is one, else names of p
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in mods else mod for a in node.names]
        else:
            continue
        out |= {t for t in targets if t in mods and t != name}
    return out


def _cycle(graph: dict):
    """One import cycle as a list of modules, or None."""
    state, stack = {}, []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return stack[stack.index(n):] + [n]
            if n not in state:
                found = visit(n)
                if found:
                    return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            found = visit(m)
            if found:
                return found
    return None


def test_no_import_cycles():
    mods = _modules()
    graph = {name: _imports(name, path, mods) for name, path in mods.items()}
    assert len(graph) > 40
    assert "wavlight.cli.main" in graph and "wavlight.kernels" in graph
    assert _cycle(graph) is None, " -> ".join(_cycle(graph))


def _private_imports(name: str, path: Path, mods: dict) -> list:
    """Where module ``name`` takes another project module's private name: ``from m import _x``
    (anywhere in the file, functions included), or ``alias._x`` on a name bound to a project
    module by an import. Dunder names (``__version__``) are not private."""
    is_package = path.name == "__init__.py"
    package = name if is_package else name.rsplit(".", 1)[0]
    found, modules = [], {}

    def private(attr):
        return attr.startswith("_") and not (attr.startswith("__") and attr.endswith("__"))

    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            for a in node.names:
                if f"{mod}.{a.name}" in mods:   # a module: its alias
                    modules[a.asname or a.name] = f"{mod}.{a.name}"
                elif mod in mods and mod != name and private(a.name):
                    found.append(f"{name}:{node.lineno} imports {mod}.{a.name}")
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name in mods and a.asname:
                    modules[a.asname] = a.name
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in modules
                and modules[node.value.id] != name and private(node.attr)):
            found.append(f"{name}:{node.lineno} uses {modules[node.value.id]}.{node.attr}")
    return found


def test_no_module_takes_another_modules_private_names():
    """One concept per module, and what it offers others is public: no ``from m import _x`` nor
    ``m._x`` of another project module (the package's own __init__ included)."""
    mods = _modules()
    found = [f for name, path in sorted(mods.items()) for f in _private_imports(name, path, mods)]
    assert found == []


def test_the_private_import_finder_finds_one(tmp_path):
    (tmp_path / "a.py").write_text("def _hidden():\n    pass\n")
    (tmp_path / "b.py").write_text("from .a import _hidden\nfrom . import a\nx = a._hidden\n")
    mods = {"p.a": tmp_path / "a.py", "p.b": tmp_path / "b.py"}
    assert len(_private_imports("p.b", tmp_path / "b.py", mods)) == 2
    assert _private_imports("p.a", tmp_path / "a.py", mods) == []


def test_the_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_the_library_never_imports_the_wavlight_package_itself():
    """``import wavlight`` inside the library would tie every module to the package's __init__."""
    mods = _modules()
    offenders = [name for name, path in mods.items() if not name.startswith("wavlight.cli") and name != "wavlight"
                 and "wavlight" in _imports(name, path, mods)]
    assert offenders == []


def test_installed_top_level_names(tmp_path):
    """pip puts only the ``wavlight`` package into site-packages: cli/, kernels/ and scenes/ install
    inside it."""
    with open(ROOT / "pyproject.toml", "rb") as fh:
        tool = tomllib.load(fh)["tool"]["setuptools"]
    assert all(p == "wavlight" or p.startswith("wavlight.") for p in tool["packages"])
    assert set(tool["package-dir"]) == {"wavlight.cli", "wavlight.kernels", "wavlight.scenes"}
    # outside the checkout (no current folder on sys.path): no `cli` of ours, but wavlight.cli
    probe = ("import importlib.util as u; s = u.find_spec('cli'); print(s.origin if s else None); "
             "import wavlight.cli.main, wavlight.kernels, wavlight.scenes; print(wavlight.cli.main.__name__)")
    out = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, capture_output=True, text=True, check=True)
    origin, name = out.stdout.split()
    assert origin == "None" or not origin.startswith(str(ROOT)), origin
    assert name == "wavlight.cli.main"


def test_option_tables_in_the_docs_are_generated_from_the_declaration():
    """docs/cli.md and docs/scene-format.md carry wavlight.strategies.options_table() between their
    markers (python docs/update_tables.py rewrites them)."""
    from wavlight import strategies

    for name, scene_keys in (("cli.md", True), ("scene-format.md", True)):
        path = ROOT / "docs" / name
        if not path.exists():
            pytest.fail(f"docs/{name} is missing")
        text = path.read_text()
        found = re.search(r"<!-- options:begin -->\n(.*?)\n<!-- options:end -->", text, re.S)
        assert found, f"docs/{name} has no options table markers"
        assert found.group(1).strip() == strategies.options_table(scene_keys).strip(), \
            f"docs/{name}: run python docs/update_tables.py"


def test_every_option_reaches_scene_cli_experiment_and_render_full(tmp_path):
    """One declaration, four readers: each option is a [render] key, a flag of `wavlight render`,
    a [[strategies]] key of experiment files, and a render_full keyword."""
    import click

    import wavlight
    from wavlight.cli.main import render
    from wavlight.evaluation.spec import load_spec
    from wavlight.strategies import APPLIES, OPTIONS

    flags = {o for p in render.params if isinstance(p, click.Option) for o in p.opts + p.secondary_opts}
    for key, option in OPTIONS.items():
        value = option.default if option.default is not None else (option.values or (option.hi,))[-1]
        scene = wavlight.load_dict({"render": {key: value}, "environment": {"procedural": "sky"}})
        assert scene.options == {key: option.kind(value)}, key
        assert option.flag in flags, key
        if option.kind is bool:
            assert option.off_flag in flags, key
        sid = APPLIES[key][0]
        spec = tmp_path / f"{key}.toml"
        scene_path = tmp_path / "s.toml"
        scene_path.write_text('[environment]\nprocedural = "sky"\n')
        literal = str(value).lower() if option.kind is bool else (f'"{value}"' if option.kind is str else value)
        spec.write_text(f'[[scenes]]\npath = "s.toml"\n[[strategies]]\nid = "{sid}"\n{key} = {literal}\n'
                        "[budgets]\nspp = [1]\n")
        assert load_spec(spec).strategies[0].options == {key: option.kind(value)}, key
        assert os.path.basename(scene_path) == "s.toml"
    with pytest.raises(wavlight.WavlightError, match="unknown option 'no_such_option'"):
        wavlight.render_full(wavlight.load_dict({"environment": {"procedural": "sky"}}), no_such_option=1)


def test_tests_mirror_the_packages():
    """The tests of each package of wavlight live in the folder of its name (tests/haar/ for
    wavlight.haar), the command line's in tests/cli/, hostile input in tests/hostile/, the tests
    of top-level modules in tests/, and the helpers they share in tests/support/ (on pytest's
    pythonpath)."""
    tests = ROOT / "tests"
    packages = {p.name for p in (ROOT / "wavlight").iterdir() if (p / "__init__.py").is_file()}
    for name in packages:
        assert any((tests / name).glob("test_*.py")), f"tests/{name}/ holds no tests of wavlight.{name}"
    folders = {p.name for p in tests.iterdir() if p.is_dir() and not p.name.startswith((".", "__"))}
    assert folders <= packages | {"cli", "hostile", "support"}, folders - packages
    helpers = [p for p in tests.rglob("*.py") if not p.name.startswith("test_") and p.name != "conftest.py"]
    assert all(p.parent == tests / "support" for p in helpers), helpers
    assert not any((tests / "support").glob("test_*.py"))
