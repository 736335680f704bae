"""The abstract/final pattern (equinox's `docs/pattern.md`) across the package: every
equinox Module either is abstract or is final, and no class overrides a method or
property that a base class in elasticoop already implements. Also: no `hasattr`
dispatch in the package source."""

import abc
import ast
import importlib
import inspect
import pathlib
import pkgutil

import equinox as eqx

import elasticoop

PACKAGE = pathlib.Path(elasticoop.__file__).parent


def _package_modules():
    for info in pkgutil.walk_packages(elasticoop.__path__, "elasticoop."):
        if info.name.endswith("__main__"):  # runs the demo on import
            continue
        yield importlib.import_module(info.name)


def _modules_classes() -> dict[str, type]:
    found = {}
    for module in _package_modules():
        for obj in vars(module).values():
            if (
                inspect.isclass(obj)
                and issubclass(obj, eqx.Module)
                and obj.__module__.startswith("elasticoop")
            ):
                found[f"{obj.__module__}.{obj.__qualname__}"] = obj
    return found


def _is_abstract(member) -> bool:
    target = member.fget if isinstance(member, property) else member
    return bool(getattr(target, "__isabstractmethod__", False))


def concrete_overrides(cls: type, prefix: str = "elasticoop") -> list[str]:
    """Methods and properties of `cls` that replace a concrete implementation in a
    base class whose module starts with `prefix`."""
    out = []
    for name, member in vars(cls).items():
        if name.startswith("__") or not (
            callable(member) or isinstance(member, property)
        ):
            continue
        for base in cls.__mro__[1:]:
            if name in vars(base):
                if base.__module__.startswith(prefix) and not _is_abstract(
                    vars(base)[name]
                ):
                    out.append(
                        f"{cls.__qualname__}.{name} overrides {base.__qualname__}"
                    )
                break
    return out


def test_the_override_check_can_fail():
    class Base(eqx.Module):
        @abc.abstractmethod
        def abstract(self) -> int: ...

        def concrete(self) -> int:
            return 1

    class Final(Base):
        def abstract(self) -> int:
            return 2

        def concrete(self) -> int:
            return 3

    assert concrete_overrides(Final, prefix=__name__) == [
        "test_the_override_check_can_fail.<locals>.Final.concrete overrides "
        "test_the_override_check_can_fail.<locals>.Base"
    ]


def test_no_concrete_method_is_overridden():
    classes = _modules_classes()
    assert len(classes) > 30  # the walk found the package's modules
    problems = [p for cls in classes.values() for p in concrete_overrides(cls)]
    assert problems == []


def test_classes_are_abstract_or_final():
    """A class with subclasses in the package is abstract (named `Abstract...`)."""
    classes = _modules_classes().values()
    for cls in classes:
        subclassed = any(c is not cls and issubclass(c, cls) for c in classes)
        if subclassed:
            assert cls.__name__.startswith("Abstract"), cls


def test_no_hasattr_dispatch():
    calls = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Name)
                and node.func.id == "hasattr"
            ):
                calls.append(f"{path.relative_to(PACKAGE)}:{node.lineno}")
    assert calls == []
