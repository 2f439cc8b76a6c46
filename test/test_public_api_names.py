"""The package touches only public names of rclpy and aiohttp (parsed, not grepped).

Every module of ``audio2pose_ros`` is parsed; the names it imports from rclpy and aiohttp, and
the attribute chains it reads on them (``rclpy.executors.SingleThreadedExecutor``,
``web.Application``), are listed by their full dotted name. A name is private when one of its
parts starts with an underscore (dunders aside), when a part is ``handle`` (rclpy's C handles),
or when it lies under ``rclpy.impl.implementation_singleton`` (rclpy's C module). In a module
that imports rclpy or aiohttp, reading ``.handle`` or an underscore attribute of an object that
is not the module's own (``self``, ``cls``) is private too: that is how ``service.handle`` or
``subscription._callback_type`` are reached; so is ``self._name`` in a class derived from a
library class that defines ``_name`` (an aiohttp ``BaseSite``'s ``_backlog``). An exception, when
one is truly needed, is one line of ``public_api_allowlist.txt`` beside this file, with its
reason.
"""

from __future__ import annotations

import ast
import importlib
import inspect
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import pytest

import audio2pose_ros

PACKAGE = Path(audio2pose_ros.__file__).parent
LIBRARIES = ("rclpy", "aiohttp")
ALLOWLIST = Path(__file__).with_name("public_api_allowlist.txt")
C_MODULE = "rclpy.impl.implementation_singleton"
OWN_OBJECTS = frozenset({"self", "cls"})


class Use(NamedTuple):
    """A name of a library (or a private attribute) used at a place of the package."""

    name: str  # full dotted name, or ``<object>.<attribute>`` for an attribute of an object
    where: str  # path:line


def is_private(name: str) -> bool:
    """Whether a dotted name is private: an underscore part, ``handle``, or rclpy's C module."""
    parts = name.split(".")
    underscore = any(
        p.startswith("_") and not (p.startswith("__") and p.endswith("__")) for p in parts
    )
    return underscore or "handle" in parts or name.startswith(C_MODULE)


def _imported(tree: ast.Module) -> dict[str, str]:
    """Local name -> full dotted name, for every import of a library in a module."""
    bound: dict[str, str] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] in LIBRARIES:
                    local = alias.asname or alias.name.split(".")[0]
                    bound[local] = alias.name if alias.asname else local
        elif (
            isinstance(node, ast.ImportFrom)
            and node.module
            and node.level == 0
            and node.module.split(".")[0] in LIBRARIES
        ):
            for alias in node.names:
                bound[alias.asname or alias.name] = f"{node.module}.{alias.name}"
    return bound


def _chain(node: ast.AST) -> list[str] | None:
    """``a.b.c`` as ["a", "b", "c"]; None when the chain does not start with a plain name."""
    parts: list[str] = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if not isinstance(node, ast.Name):
        return None
    parts.append(node.id)
    return parts[::-1]


def _resolve(name: str) -> object | None:
    """The object a full dotted name stands for, None when it cannot be found."""
    parts = name.split(".")
    for split in range(len(parts), 0, -1):  # the longest importable module, then attributes
        try:
            found: object = importlib.import_module(".".join(parts[:split]))
        except ImportError:
            continue
        try:
            for attr in parts[split:]:
                found = getattr(found, attr)
        except AttributeError:
            return None
        return found
    return None


def _inherited_private(cls: ast.ClassDef, bound: dict[str, str], where: str) -> Iterator[Use]:
    """``self._name`` in a class derived from a library class that defines ``_name``."""
    bases = []
    for base in cls.bases:
        chain = _chain(base)
        if chain is not None and chain[0] in bound:
            full = ".".join([bound[chain[0]], *chain[1:]])
            found = _resolve(full)
            if isinstance(found, type):
                bases.append((full, found))
    for node in ast.walk(cls):
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id == "self"
            and is_private(node.attr)
        ):
            for full, base_class in bases:
                for klass in base_class.__mro__:
                    if klass.__module__.split(".")[0] not in LIBRARIES:
                        continue
                    try:
                        source = inspect.getsource(klass)
                    except (OSError, TypeError):
                        source = ""
                    if node.attr in vars(klass) or f"self.{node.attr}" in source:
                        yield Use(f"{full}.{node.attr}", f"{where}:{node.lineno}")
                        break


def uses(path: Path) -> Iterator[Use]:
    """The library names and the private attributes of objects that ``path`` touches."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    where = (
        path.relative_to(PACKAGE.parent).as_posix() if path.is_relative_to(PACKAGE) else path.name
    )
    bound = _imported(tree)
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef):
            yield from _inherited_private(node, bound, where)
        elif isinstance(node, ast.ImportFrom | ast.Import):
            for name in _imported(ast.Module(body=[node], type_ignores=[])).values():
                yield Use(name, f"{where}:{node.lineno}")
        elif isinstance(node, ast.Attribute) and not isinstance(node.ctx, ast.Del):
            chain = _chain(node)
            if chain is not None and chain[0] in bound:
                yield Use(".".join([bound[chain[0]], *chain[1:]]), f"{where}:{node.lineno}")
            elif bound and (node.attr == "handle" or is_private(node.attr)):
                owner = chain[0] if chain is not None and len(chain) == 2 else None
                if owner not in OWN_OBJECTS:
                    base = ast.unparse(node.value)
                    yield Use(f"<{base}>.{node.attr}", f"{where}:{node.lineno}")


def allowed() -> dict[str, str]:
    """The allow-list: name -> reason (``name  # reason`` per line; ``#`` lines are comments)."""
    entries: dict[str, str] = {}
    for line in ALLOWLIST.read_text(encoding="utf-8").splitlines():
        if line.strip() and not line.lstrip().startswith("#"):
            name, _, reason = line.partition("#")
            assert reason.strip(), f"allow-list entry {name.strip()!r} gives no reason"
            entries[name.strip()] = reason.strip()
    return entries


def package_uses() -> list[Use]:
    return [use for path in sorted(PACKAGE.rglob("*.py")) for use in uses(path)]


def test_when_the_package_is_parsed_expect_no_private_rclpy_or_aiohttp_name():
    touched = package_uses()
    names = sorted({use.name for use in touched if not use.name.startswith("<")})
    print("rclpy and aiohttp names the package touches:\n  " + "\n  ".join(names))
    assert any(name.startswith("rclpy.") for name in names)  # the parse found the ROS layer
    exceptions = allowed()
    private = sorted(
        {f"{use.name} ({use.where})" for use in touched if is_private(use.name)}
        - {f"{use.name} ({use.where})" for use in touched if use.name in exceptions}
    )
    assert private == [], "private names:\n" + "\n".join(private)


def test_when_the_allowlist_names_a_name_expect_the_package_still_to_touch_it():
    touched = {use.name for use in package_uses()}
    stale = sorted(set(allowed()) - touched)
    assert stale == [], f"allow-list entries the package no longer touches: {stale}"


def test_when_a_touched_rclpy_name_is_looked_up_expect_it_in_this_rclpy():
    """Every rclpy name the package imports or reads exists (a typo would hide a fallback)."""
    names = {use.name for use in package_uses() if use.name.startswith("rclpy.")}
    missing = sorted(name for name in names if _resolve(name) is None)
    assert missing == [], missing


@pytest.mark.parametrize(
    ("source", "private"),
    [
        ("from rclpy.impl.implementation_singleton import rclpy_implementation", True),
        ("from rclpy.impl import implementation_singleton", True),
        ("import rclpy\nrclpy.node._private", True),
        ("import rclpy\ndef f(service):\n    return service.handle.take()", True),
        ("import rclpy\ndef f(sub):\n    sub._callback_type = 1", True),
        ("import aiohttp\ndef f(site):\n    return site._server", True),
        (
            "from aiohttp import web\nclass S(web.BaseSite):\n    def f(self):\n"
            "        self._backlog",
            True,
        ),
        ("from rclpy.node import Node\nNode.get_name", False),
        ("import rclpy\nclass A:\n    def f(self):\n        return self._own", False),
        ("def f(x):\n    return x._free", False),  # no library imported: not about them
    ],
)
def test_when_a_module_uses_a_name_expect_it_judged_private_or_public(tmp_path, source, private):
    path = tmp_path / "probe.py"
    path.write_text(source, encoding="utf-8")
    found = list(uses(path))
    assert any(is_private(use.name) or use.name.endswith(".handle") for use in found) is private
