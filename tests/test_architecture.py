"""The package's shape: imports go one way (shared pieces <- sensor models <- worlds <- tools), no cycles,
and a lazy front door whose every public name resolves."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "sensor_envs"

# Layer of each top-level part of the package: a module may import only from its own layer or lower ones.
LAYERS = {
    "geometry": 0,
    "maps": 0,
    "modelio": 0,
    "constraints": 0,
    "sensor_model": 0,
    "rng": 0,
    "jit": 0,
    "trig": 0,
    "heap": 0,
    "lazy": 0,
    "outputs": 0,
    "inputs": 0,
    "cards": 0,
    "lidar": 1,
    "radar": 1,
    "envs": 2,
    "diagnose": 3,
    "evaluate": 3,
    "training": 3,
    "cli": 4,
    "testing": 5,
}
# Sensor domains that must not import each other.
SEPARATE = {("lidar", "radar"), ("radar", "lidar")}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _runtime_nodes(tree: ast.AST) -> list[ast.AST]:
    """Every node of ``tree`` except those under ``if TYPE_CHECKING:`` (type-only imports run never)."""
    out: list[ast.AST] = []
    stack = [tree]
    while stack:
        node = stack.pop()
        out.append(node)
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            stack.extend(node.orelse)
            continue
        stack.extend(ast.iter_child_nodes(node))
    return out


def _imports(path: Path) -> set[str]:
    """Every ``sensor_envs`` module imported at run time anywhere in the file (top level or inside functions)."""
    found: set[str] = set()
    for node in _runtime_nodes(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("sensor_envs"))
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("sensor_envs"):
            found.add(node.module)
    return found


def _part(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


GRAPH = {_module_name(p): _imports(p) for p in sorted(PACKAGE.rglob("*.py"))}


def test_every_part_of_the_package_has_a_layer():
    parts = {_part(m) for m in GRAPH} - {None}
    assert parts <= set(LAYERS) | {"models"}, sorted(parts - set(LAYERS))


@pytest.mark.parametrize("module", sorted(m for m in GRAPH if _part(m)))
def test_imports_go_one_way(module):
    mine = _part(module)
    for target in GRAPH[module]:
        theirs = _part(target)
        if theirs is None or theirs == "models":
            continue
        assert LAYERS[theirs] <= LAYERS[mine], (
            f"{module} (layer {LAYERS[mine]}) imports {target} (layer {LAYERS[theirs]})"
        )
        assert (mine, theirs) not in SEPARATE, f"{module} imports {target}: lidar and radar stay apart"


def test_no_import_cycles():
    def resolve(target: str) -> str | None:  # "sensor_envs.x.y" may name a module or a package
        return target if target in GRAPH else None

    state: dict[str, int] = {}

    def visit(module: str, path: list[str]) -> None:
        state[module] = 1
        for target in sorted(GRAPH[module]):
            t = resolve(target)
            if t is None or t == "sensor_envs":
                continue
            if state.get(t) == 1:
                raise AssertionError("import cycle: " + " -> ".join([*path, module, t]))
            if t not in state:
                visit(t, [*path, module])
        state[module] = 2

    for module in GRAPH:
        if module not in state:
            visit(module, [])


def _passes_in_a_fresh_interpreter(code: str) -> None:
    """Run ``code`` in a new Python process (nothing of this one's imports); it must exit 0."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr + out.stdout


def test_front_door_is_lazy_and_complete():
    code = (
        "import sys, sensor_envs\n"
        "loaded = sorted(m for m in sys.modules if m.startswith('sensor_envs.'))\n"
        "print(loaded)\n"
        "assert not loaded, loaded\n"
        "for name in sensor_envs.__all__:\n"
        "    assert getattr(sensor_envs, name) is not None, name\n"
        "assert sorted(dir(sensor_envs)) == sorted(sensor_envs.__all__)\n"
    )
    _passes_in_a_fresh_interpreter(code)


def test_unknown_public_name_is_an_attribute_error():
    import sensor_envs

    with pytest.raises(AttributeError, match="no attribute 'NoSuchThing'"):
        sensor_envs.NoSuchThing  # noqa: B018


PACKAGES = sorted(p.parent for p in PACKAGE.rglob("__init__.py"))


@pytest.mark.parametrize("package", PACKAGES, ids=lambda p: _module_name(p / "__init__.py"))
def test_package_docstring_names_all_its_modules(package):
    """Each package's docstring names every module and subpackage in it (as a word, e.g. ``kde``)."""
    doc = ast.get_docstring(ast.parse((package / "__init__.py").read_text())) or ""
    children = [p.stem for p in package.glob("*.py") if p.stem != "__init__"]
    children += [p.name for p in package.iterdir() if (p / "__init__.py").is_file()]
    name = _module_name(package / "__init__.py")
    missing = [
        c for c in sorted(children) if not re.search(rf"((?<![\w.])|{re.escape(name)}\.){re.escape(c)}(?!\w)", doc)
    ]
    assert not missing, f"{name}: docstring does not name {missing}"


# Every subpackage hands on a curated public API; the command line's interface is the ``sensor-envs`` command,
# and ``testing`` holds the suite's and benchmarks' case generators (no user API).
API_PACKAGES = sorted(
    _module_name(p / "__init__.py") for p in PACKAGES if p != PACKAGE and p.name not in ("cli", "testing")
)


@pytest.mark.parametrize("package", API_PACKAGES)
def test_subpackage_exports_its_public_names(package):
    """A non-empty ``__all__`` in each subpackage's ``__init__``, every name of it resolving from the package."""
    import importlib

    pkg = importlib.import_module(package)
    assert pkg.__all__, f"{package}: no __all__"
    assert len(set(pkg.__all__)) == len(pkg.__all__), f"{package}: duplicates in __all__"
    missing = [n for n in pkg.__all__ if getattr(pkg, n, None) is None]
    assert not missing, f"{package}: {missing} do not resolve"


LAZY_PACKAGES = [
    "sensor_envs.lidar",
    "sensor_envs.radar",
    "sensor_envs.evaluate",
    "sensor_envs.envs",
    "sensor_envs.training",
]


@pytest.mark.parametrize("package", LAZY_PACKAGES)
def test_subpackage_exports_are_lazy(package):
    """Importing a subpackage (in a fresh interpreter) imports none of its modules; ``dir`` lists its exports and
    an unknown name is an ``AttributeError``. That its names resolve: ``test_subpackage_exports_resolve``."""
    code = (
        "import importlib, sys\n"
        f"pkg = importlib.import_module({package!r})\n"
        f"loaded = sorted(m for m in sys.modules if m.startswith({package + '.'!r}))\n"
        "assert not loaded, loaded\n"
        "assert sorted(dir(pkg)) == sorted(pkg.__all__)\n"
        "try:\n"
        "    pkg.NoSuchThing\n"
        "except AttributeError:\n"
        "    pass\n"
        "else:\n"
        "    raise AssertionError('unknown name resolved')\n"
    )
    _passes_in_a_fresh_interpreter(code)


def test_subpackage_exports_resolve():
    """In one fresh interpreter (the modules behind the names are heavy to import, once is enough): every name
    each lazy subpackage exports resolves to its module's own object, which that module exports too."""
    code = (
        "import importlib\n"
        f"for package in {LAZY_PACKAGES!r}:\n"
        "    pkg = importlib.import_module(package)\n"
        "    for name, module in pkg._PUBLIC.items():\n"
        "        mod = importlib.import_module(module)\n"
        "        assert getattr(pkg, name) is getattr(mod, name), (package, name)\n"
        "        assert name in getattr(mod, '__all__', [name]), (package, name, module)\n"
        "        assert not hasattr(mod, '__path__') or name in mod.__all__, (package, name)\n"
    )
    _passes_in_a_fresh_interpreter(code)


@pytest.mark.parametrize("package", [*LAZY_PACKAGES, "sensor_envs.diagnose"])
def test_exported_names_are_not_module_names(package):
    """``from pkg import x`` must not mean a module or a function depending on what was imported before."""
    import importlib

    pkg = importlib.import_module(package)
    modules = {p.stem for p in Path(pkg.__file__).parent.glob("*.py")} | {
        p.name for p in Path(pkg.__file__).parent.iterdir() if (p / "__init__.py").is_file()
    }
    assert not set(pkg.__all__) & modules, sorted(set(pkg.__all__) & modules)


ROOT = PACKAGE.parent
BENCHMARKS = sorted((ROOT / "benchmarks").glob("*.py"))


def _loads_a_benchmark(path: Path) -> bool:
    text = path.read_text(encoding="utf-8")
    return "benchmarks" in text and ("spec_from_file_location" in text or "sys.path" in text)


def test_no_test_imports_a_benchmark_script():
    tests = [p for p in (ROOT / "tests").glob("test_*.py") if p.name != Path(__file__).name]
    found = {p.name for p in tests if _loads_a_benchmark(p)}
    assert not found, sorted(found)


def test_no_benchmark_imports_another():
    names = {p.stem for p in BENCHMARKS}
    found = set()
    for path in BENCHMARKS:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                found |= {(path.stem, a.name) for a in node.names if a.name in names}
            elif isinstance(node, ast.ImportFrom) and node.module in names:
                found.add((path.stem, node.module))
        text = path.read_text(encoding="utf-8")
        found |= {(path.stem, n) for n in names if n != path.stem and f"{n}.py" in text and "spec_from_file" in text}
    assert not found, sorted(found)


def _imported_modules(path: Path) -> set[str]:
    """Top-level names of every module ``path`` imports (anywhere in the file)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            found.add(node.module.split(".")[0])
    return found


def test_no_benchmark_imports_a_test_module():
    """Shared case generators live in ``sensor_envs.testing``: a benchmark neither puts ``tests/`` on the path
    nor imports a module of it (issue 40)."""
    test_modules = {p.stem for p in (ROOT / "tests").glob("*.py")} | {"tests"}
    found = set()
    for path in BENCHMARKS:
        text = path.read_text(encoding="utf-8")
        found |= {(path.stem, m) for m in _imported_modules(path) & test_modules}
        if re.search(r"""sys\.path.*["']tests["']|parents\[\d\]\s*/\s*["']tests["']""", text):
            found.add((path.stem, "tests/ on sys.path"))
    assert not found, sorted(found)


UNBOUNDED_READ = re.compile(r"yaml\.(safe_)?load\(|np\.load\(|json\.load\(|json\.loads\([^)\n]*\.read_(text|bytes)\(")


def test_every_file_is_parsed_through_the_input_layer():
    """YAML, JSON and .npz files are parsed by ``sensor_envs.inputs`` only (bounded reads, no alias bombs, no
    duplicate keys; issue 42): a ``yaml.safe_load`` of a user's config once hung on a FIFO."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        if rel == "inputs.py" or rel.startswith("testing/"):
            continue
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if UNBOUNDED_READ.search(line):
                found.append(f"{rel}:{n}: {line.strip()}")
    assert not found, found


def test_no_path_is_resolved_with_path_resolve():
    """Paths are resolved by ``sensor_envs.inputs.real_path``: ``Path.resolve()`` raises ``RuntimeError`` on a
    symbolic-link loop (Python < 3.13), which an ``--out`` or a ``--map`` naming a loop turned into a traceback
    (issue 42)."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if ".resolve()" in line and not line.strip().startswith(("#", '"', "``")):
                found.append(f"{rel}:{n}: {line.strip()}")
    assert not found, found
