"""Names imported on first use (PEP 562).

A package lists its lazily imported names once, as imports under
`typing.TYPE_CHECKING` (which type checkers and the documentation read);
`lazy_attributes` turns that list into the package's `__getattr__` and `__dir__`, so
that importing the package does not import what those names need.
"""

import ast
import importlib
import os
import pathlib
import sys
import types
from collections.abc import Callable
from typing import Any


def use_float64() -> None:
    """Turn on JAX's 64-bit mode (`jax_enable_x64`) without importing JAX: at once
    if JAX is imported already, else through `JAX_ENABLE_X64`, which JAX reads when
    it is imported."""
    config = getattr(sys.modules.get("jax"), "config", None)
    if config is not None:
        config.update("jax_enable_x64", True)
    else:
        os.environ["JAX_ENABLE_X64"] = "1"


def lazy_names(init_file: str) -> dict[str, str]:
    """Name -> module (relative to the package) of the imports under
    `typing.TYPE_CHECKING` in the package's `__init__.py`; a submodule imported as
    `from . import name` maps to `.name`."""
    tree = ast.parse(pathlib.Path(init_file).read_text(encoding="utf-8"))
    block = next(
        node
        for node in tree.body
        if isinstance(node, ast.If) and ast.unparse(node.test) == "typing.TYPE_CHECKING"
    )
    names = {}
    for statement in block.body:
        assert isinstance(statement, ast.ImportFrom)
        module = "." * statement.level + (statement.module or "")
        for alias in statement.names:
            if module == ".":  # `from . import montecarlo`: the submodule itself
                names[alias.name] = "." + alias.name
            else:
                names[alias.asname or alias.name] = module
    return names


def lazy_attributes(
    package: str, init_file: str
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """`(__getattr__, __dir__)` for `package`: a name of `lazy_names` is imported
    on first access and then kept in the package's namespace."""
    lazy = lazy_names(init_file)

    def __getattr__(name: str) -> Any:
        module = lazy.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        imported = importlib.import_module(module, package)
        value = imported if module == "." + name else getattr(imported, name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        # (not the modules the package imports for itself, such as `typing`, nor
        # its private submodules: only those of `lazy` are public)
        namespace = vars(sys.modules[package])
        own = {
            name
            for name, value in namespace.items()
            if not isinstance(value, types.ModuleType)
        }
        return sorted(own | set(lazy))

    return __getattr__, __dir__
