"""The package layout is the pipeline: a folder imports only folders below it, and only ``ros/``
imports ROS.

Layers, bottom to top (doc/architecture.md): the shared base (errors, the frame grid, parameter
specs, resources, bounded file and YAML reading), then ``audio`` and ``robot``, ``motion``,
``models``, ``checkpoints``, ``data``, ``offline``, ``viz``, ``learning``, ``ros``, ``cli``. Every
import in every module is checked, function-level ones included, from the source with
:mod:`ast`; so is the absence of import circles.
"""

import ast
from pathlib import Path

import pytest

PACKAGE = "audio2pose_ros"
PACKAGE_DIR = Path(__file__).resolve().parent.parent / PACKAGE

#: Rank of each top-level module or folder of the package. A module may import lower ranks, and
#: its own rank only inside its own folder or, for the rank-0 base modules, among themselves.
LAYERS: dict[str, int] = {
    "__init__": 0,
    "errors": 0,
    "files": 0,
    "timebase": 0,
    "topics": 0,
    "parameters": 0,
    "resources": 0,
    "audio": 1,
    "robot": 1,
    "voice": 1,  # the voice out of the robot: framing, delay, latencies, NAOqi client
    "motion": 2,
    "models": 3,
    "checkpoints": 4,
    "data": 5,
    "offline": 6,
    "viz": 7,
    "learning": 8,
    "style": 9,
    "console": 10,  # its learning child process runs style's enrollment
    "ros": 11,
    "cli": 12,
}

#: Top-level modules of ROS 2 (client library, launch, message packages) that only ``ros/`` may
#: import. ``ament_index_python`` (a path lookup, no middleware) is allowed for resources.
ROS_MODULES = frozenset(
    {
        "rclpy",
        "rosidl_runtime_py",
        "launch",
        "launch_ros",
        "launch_testing",
        "rcl_interfaces",
        "builtin_interfaces",
        "std_msgs",
        "std_srvs",
        "sensor_msgs",
        "trajectory_msgs",
        "diagnostic_msgs",
        "geometry_msgs",
        "tf2_msgs",
        "audio_common_msgs",
        "naoqi_bridge_msgs",
        "rosbag2_py",
    }
)


def imported_modules(source: str) -> list[tuple[int, str]]:
    """Every absolute module name ``source`` imports, with its line, nested imports included."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module == PACKAGE:
                found += [(node.lineno, f"{PACKAGE}.{alias.name}") for alias in node.names]
            else:
                found.append((node.lineno, node.module))
    return found


def layer_of(module: str) -> str:
    """The top-level module or folder of ``audio2pose_ros.<module>``."""
    return module.split(".")[1] if "." in module else "__init__"


def violations(module: str, source: str) -> list[str]:
    """The layering rules ``module`` (dotted name) breaks with the imports in ``source``."""
    own = layer_of(module)
    found = []
    for line, name in imported_modules(source):
        top = name.split(".")[0]
        if top in ROS_MODULES and own != "ros":
            found.append(f"{module}:{line} imports {name}: only {PACKAGE}.ros may import ROS")
        if top != PACKAGE or name == PACKAGE:
            continue
        target = layer_of(name)
        if target not in LAYERS:
            found.append(f"{module}:{line} imports {name}: {target!r} is not a known layer")
        elif LAYERS[target] > LAYERS[own] or (LAYERS[target] == LAYERS[own] != 0 and target != own):
            found.append(
                f"{module}:{line} imports {name}: layer {target} ({LAYERS[target]}) is not below "
                f"{own} ({LAYERS[own]})"
            )
    return found


def package_modules() -> list[tuple[str, Path]]:
    """(dotted name, path) of every module of the package."""
    modules = []
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        parts = path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts
        modules.append((".".join(parts), path))
    return modules


def test_every_folder_and_top_level_module_has_a_layer():
    tops = {path.relative_to(PACKAGE_DIR).parts[0] for _, path in package_modules()}
    unknown = sorted(
        top.removesuffix(".py") for top in tops if top.removesuffix(".py") not in LAYERS
    )
    assert unknown == []


@pytest.mark.parametrize(("module", "path"), package_modules(), ids=lambda value: str(value))
def test_module_imports_only_lower_layers_and_no_ros_outside_ros(module, path):
    assert violations(module, path.read_text()) == []


def test_checker_reports_an_upward_import_and_ros_outside_ros():
    source = "import rclpy\n\ndef f():\n    from audio2pose_ros.ros.graph import Supervisor\n"
    found = violations("audio2pose_ros.motion.filter", source)
    assert len(found) == 2
    assert "only audio2pose_ros.ros may import ROS" in found[0]
    assert "layer ros (11) is not below motion (2)" in found[1]


def test_checker_reports_a_sideways_import_between_folders_of_one_rank():
    found = violations("audio2pose_ros.audio.features", "from audio2pose_ros import robot\n")
    assert found == [
        "audio2pose_ros.audio.features:1 imports audio2pose_ros.robot: layer robot (1) is not "
        "below audio (1)"
    ]


def test_checker_accepts_imports_within_a_folder_and_downwards_and_among_the_base():
    source = (
        "from audio2pose_ros.motion import gate\nfrom audio2pose_ros.robot.description import x\n"
    )
    assert violations("audio2pose_ros.motion.filter", source) == []
    assert violations("audio2pose_ros.parameters", "from audio2pose_ros.errors import E\n") == []


def yaml_parsing_calls(source: str) -> list[int]:
    """Lines of ``yaml.<loader>(...)`` calls (safe_load, load, full_load, ...) in ``source``."""
    return [
        node.lineno
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and isinstance(node.func.value, ast.Name)
        and node.func.value.id == "yaml"
        and "load" in node.func.attr
    ]


@pytest.mark.parametrize(("module", "path"), package_modules(), ids=lambda value: str(value))
def test_yaml_is_parsed_only_by_the_bounded_alias_free_reader(module, path):
    """A few hundred bytes of nested YAML aliases expand to gigabytes: one reader refuses them."""
    if module == f"{PACKAGE}.files":
        return
    assert yaml_parsing_calls(path.read_text()) == [], f"{module}: use audio2pose_ros.files"


def test_yaml_checker_finds_a_direct_parse():
    assert yaml_parsing_calls("import yaml\nx = yaml.safe_load(t)\ny = yaml.safe_dump(x)\n") == [2]


# --- No import circles ---------------------------------------------------------------------------


def module_names() -> frozenset[str]:
    """The dotted names of the package's modules and packages (``a.b`` for ``a/b/__init__.py``)."""
    return frozenset(name.removesuffix(".__init__") for name, _ in package_modules())


def package_imports(module: str, source: str, known: frozenset[str]) -> set[str]:
    """The package's modules that ``module`` imports, at any depth (function-level included).

    ``from a.b import c`` names the module ``a.b.c`` when that is a module, else ``a.b``; relative
    imports are resolved against ``module``. Imports under ``if TYPE_CHECKING:`` are left out:
    they never run, so they cannot form a circle at run time.
    """
    tree = ast.parse(source)
    type_only = {
        id(inner)
        for node in ast.walk(tree)
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
        for statement in node.body
        for inner in ast.walk(statement)
    }
    package = module if module in known and any(k.startswith(module + ".") for k in known) else None
    base = package or module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in type_only:
            continue
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = base.split(".")
                parent = ".".join(parts[: len(parts) - node.level + 1])
                origin = f"{parent}.{node.module}" if node.module else parent
            else:
                origin = node.module or ""
            for alias in node.names:
                child = f"{origin}.{alias.name}"
                found.add(child if child in known else origin)
    return {name for name in found if name in known and name != module}


def import_graph() -> dict[str, set[str]]:
    """Module -> the package modules it imports, for every module of the package."""
    known = module_names()
    return {
        name.removesuffix(".__init__"): package_imports(
            name.removesuffix(".__init__"), path.read_text(), known
        )
        for name, path in package_modules()
    }


def import_circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan), each sorted, sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in sorted(graph.get(node, ())):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            group = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                group.append(member)
                if member == node:
                    break
            if len(group) > 1:
                circles.append(sorted(group))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return sorted(circles)


def test_no_import_circle_in_the_package():
    """No module imports, directly or through others, a module that imports it.

    Function-level imports count: deferring an import hides a circle from Python, not from the
    reader. Only ``if TYPE_CHECKING:`` imports (annotations, never executed) are left out.
    """
    assert import_circles(import_graph()) == []


TYPE_ONLY = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"


def test_circle_finder_sees_a_circle_through_a_function_level_import():
    known = frozenset({"p", "p.a", "p.b", "p.c", "p.sub", "p.sub.d"})
    graph = {
        "p.a": package_imports("p.a", "from p import b\n", known),
        "p.b": package_imports("p.b", "def f():\n    from p.c import x\n", known),
        "p.c": package_imports("p.c", "import p.a\n", known),
        "p.sub.d": package_imports(
            "p.sub.d",
            "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import p.a\n",
            known,
        ),
    }
    assert (graph["p.a"], graph["p.b"], graph["p.sub.d"]) == ({"p.b"}, {"p.c"}, set())
    assert import_circles(graph) == [["p.a", "p.b", "p.c"]]
    relative = package_imports("p.sub.d", "from .. import a\nfrom . import x\n", known)
    assert relative == {"p.a", "p.sub"}
