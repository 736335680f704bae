"""The package's import structure: layers (the import-linter contract in
pyproject.toml), no import circles, no submodule importing the package root, and
every third-party package the code imports declared as a dependency."""

import ast
import importlib
import pathlib
import shutil
import subprocess
import sys
import tomllib

import grimp
import pytest

from elasticoop._lazy import lazy_names

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "elasticoop"


@pytest.fixture(scope="module")
def graph():
    return grimp.build_graph("elasticoop", cache_dir=None)


def _circles(graph) -> list[set[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.find_modules_directly_imported_by(v):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(component)

    for module in sorted(graph.modules):
        if module not in index:
            visit(module)
    return out


def test_no_import_circles(graph):
    # grimp records function-level imports too, and `from . import x` as an
    # import of the package itself.
    assert _circles(graph) == []


def test_no_submodule_imports_the_package_root(graph):
    importers = graph.find_modules_that_directly_import("elasticoop")
    assert not importers, f"modules importing the package root: {sorted(importers)}"


@pytest.mark.skipif(shutil.which("lint-imports") is None, reason="needs import-linter")
def test_layer_contract_holds():
    out = subprocess.run(
        ["lint-imports"], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stdout + out.stderr


def _imported_top_level_packages() -> set[str]:
    names = set()
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names.add(node.module.split(".")[0])
    return names - set(sys.stdlib_module_names) - {"elasticoop"}


# Import names that differ from the distribution names in pyproject.toml.
_DISTRIBUTION = {"yaml": "pyyaml"}


def test_every_imported_package_is_declared():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = {
        dep.split(">")[0].split("=")[0].split("<")[0].split("[")[0].strip().lower()
        for dep in project["dependencies"]
    }
    imported = {_DISTRIBUTION.get(n, n).lower() for n in _imported_top_level_packages()}
    # mpl_toolkits ships with matplotlib
    imported.discard("mpl_toolkits")
    assert imported <= declared, f"imported but not declared: {imported - declared}"


def _heavy_modules_after(statement: str) -> list[str]:
    code = (
        f"import sys; {statement}; "
        "print(sorted(m for m in ('scipy', 'pandas', 'xarray', 'matplotlib', "
        "'pydantic', 'optax') if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    return ast.literal_eval(out.stdout.strip())


def test_import_leaves_the_heavy_dependencies_until_used():
    """`import elasticoop` (what a first `simulate` needs) does not import scipy,
    pandas, xarray, matplotlib, pydantic or optax, and importing `default_scenario`
    adds only pydantic (the scenario file's validation)."""
    assert _heavy_modules_after("import elasticoop") == []
    assert _heavy_modules_after("from elasticoop import default_scenario") == [
        "pydantic"
    ]


@pytest.mark.parametrize("package", ["elasticoop", "elasticoop._config"])
def test_deferred_names_resolve(package):
    """Each name a package defers resolves, to the same object as its defining
    module's, and is listed by `dir`."""
    module = importlib.import_module(package)
    deferred = lazy_names(module.__file__)
    expected = {
        "elasticoop": {"static_equilibrium", "identify", "plot_energy", "montecarlo"},
        "elasticoop._config": {"load_scenario", "load_study", "load_experiment"},
    }[package]
    assert expected <= set(deferred)
    for name, where in deferred.items():
        value = getattr(module, name)
        defining = importlib.import_module(where, package)
        assert value is (defining if where == f".{name}" else getattr(defining, name))
        assert name in dir(module)
    # and `dir` lists nothing else public (before: `typing`, which the package
    # imports for itself)
    assert {n for n in dir(module) if not n.startswith("_")} == set(deferred)
    if package == "elasticoop":  # and a star import takes the same names
        assert module.__all__ == sorted(deferred)
        star: dict = {}
        exec("from elasticoop import *", star)
        assert set(star) - {"__builtins__"} == set(deferred)
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        module.not_a_name  # noqa: B018


def _documented_layers() -> list[str]:
    """The layer list of docs/architecture.md (between its layer markers)."""
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    block = text.split("<!-- layers -->")[1].split("<!-- /layers -->")[0]
    lines = [line.strip() for line in block.strip().splitlines()]
    return [line for line in lines if line and not line.startswith("```")]


def test_architecture_page_lists_the_contracts_layers():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    contracts = config["tool"]["importlinter"]["contracts"]
    layers = next(c for c in contracts if c.get("containers") == ["elasticoop"])
    assert _documented_layers() == layers["layers"]


def test_engine_imports_no_physics(graph):
    """The engine (`elasticoop._integrate`) knows diffrax and no bodies: nothing of
    it imports a module of the physics or of `simulate`."""
    engine = {m for m in graph.modules if m.startswith("elasticoop._integrate")}
    physics = (
        "_simulate _trajectory _status _lagrange _models _forces _motion _body "
        "_mass_blocks _rotations"
    ).split()
    for module in engine:
        for imported in graph.find_modules_directly_imported_by(module):
            parts = imported.split(".")
            assert len(parts) < 2 or parts[1] not in physics, (module, imported)


def test_diffrax_within_the_supported_window():
    """The installed diffrax is one whose private details `_compat` was read in,
    and pyproject.toml bounds the dependency to the same window."""
    from elasticoop import _compat

    _compat.check_diffrax_version()
    with pytest.raises(RuntimeError, match="supports diffrax>=0.7.0,<0.8.0"):
        _compat.check_diffrax_version("0.8.0")
    first, end = _compat.SUPPORTED_DIFFRAX
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    (spec,) = [d for d in config["project"]["dependencies"] if d.startswith("diffrax")]
    low = ".".join(map(str, first[:2]))
    high = ".".join(map(str, end[:2]))
    assert spec == f"diffrax>={low},<{high}"
