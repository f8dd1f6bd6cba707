"""Architecture: imports run one way (docs/architecture.md), and neither package has a cycle.

service/ is layered, outermost first: the Python client (client/), the edge (main, config,
healthcheck, http/, api/), observability/, models/, pipeline/, the contract (errors,
manifest, wire). A module imports its own layer or the layers inside it, never one
outside; the client imports nothing of service/ but the contract; service/ never imports
training/; training/ uses the service's contract, pipeline and models, never its edge;
tools/ never imports tests/ (the container test checks answers with the references in
training/evaluate/references/, not with test code). Every import counts, also one inside
a function. The connect stage (service/pipeline/connect/) is a package with a chosen
public API: code outside it imports only the names of its `__all__`, never its modules
(its own tests, under tests/service/pipeline/connect/, test the modules). Within
training/sweep/, each module imports only those before it: plan, measures, rule,
reasons, search, command. The checks run over the real tree; each checker is tried on a
synthetic tree first, so a test that
cannot fail is caught.
"""

from __future__ import annotations

import ast
from collections.abc import Iterable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# service/ layers, innermost first: (layer, module prefixes). A module may import only
# modules of its own layer or of a layer before it in this list.
SERVICE_LAYERS: list[tuple[str, tuple[str, ...]]] = [
    ("contract", ("service.errors", "service.manifest", "service.wire")),
    ("pipeline", ("service.pipeline",)),
    ("models", ("service.models",)),
    ("observability", ("service.observability",)),
    (
        "edge",
        ("service.http", "service.api", "service.main", "service.config", "service.healthcheck"),
    ),
    # Runs in a planner's process, not the server's: it shares only the wire models.
    ("client", ("service.client",)),
]
CLIENT_MAY_IMPORT = ("contract", "client")
PIPELINE = [name for name, _ in SERVICE_LAYERS].index("pipeline")
# What training/ may import from service/: the shared schema, the domain, the loaded models.
TRAINING_MAY_IMPORT = ("contract", "pipeline", "models")
# Third-party packages that belong to an outer layer: the pipeline takes models through
# Protocols and returns typed containers, so it never needs these.
PIPELINE_FORBIDDEN_PACKAGES = (
    "onnxruntime",
    "fastapi",
    "starlette",
    "uvicorn",
    "prometheus_client",
    "pydantic_settings",
    "torch",
    "pytorch_kinematics",
    "coal",  # the training's collision reference; the service checks spheres in numpy
)


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(source: str, module: str, is_package: bool) -> set[str]:
    """Every module `source` imports, anywhere in it (absolute names; relative resolved)."""
    found: set[str] = set()
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            found.add(base)
            # `from package import module` imports the submodule too.
            found.update(f"{base}.{alias.name}" for alias in node.names)
    return found


def import_graph(root: Path, packages: Iterable[str]) -> dict[str, set[str]]:
    """module -> the modules it imports, for every module under the given packages."""
    graph: dict[str, set[str]] = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            name = module_name(path, root)
            graph[name] = imported_modules(path.read_text(), name, path.name == "__init__.py")
    return graph


def layer_of(module: str) -> int | None:
    """Index of the service layer `module` belongs to, or None outside service/."""
    for index, (_, prefixes) in enumerate(SERVICE_LAYERS):
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return index
    return None


def direction_violations(graph: dict[str, set[str]]) -> list[str]:
    """Imports against the direction of docs/architecture.md, as readable lines."""
    allowed_for_training = {
        i for i, (name, _) in enumerate(SERVICE_LAYERS) if name in TRAINING_MAY_IMPORT
    }
    violations = []
    for module, imports in sorted(graph.items()):
        top = module.split(".")[0]
        own = layer_of(module)
        for imported in sorted(imports):
            target = layer_of(imported)
            imported_top = imported.split(".")[0]
            if top == "service" and imported_top == "training":
                violations.append(f"{module} imports {imported}: service never imports training")
            elif own is not None and target is not None and target > own:
                violations.append(
                    f"{module} ({SERVICE_LAYERS[own][0]}) imports {imported} "
                    f"({SERVICE_LAYERS[target][0]}): an outer layer"
                )
            elif top == "training" and target is not None and target not in allowed_for_training:
                violations.append(
                    f"{module} imports {imported} ({SERVICE_LAYERS[target][0]}): training uses "
                    f"only the service's {', '.join(TRAINING_MAY_IMPORT)}"
                )
            if own == PIPELINE and imported_top in PIPELINE_FORBIDDEN_PACKAGES:
                violations.append(f"{module} (pipeline) imports {imported}")
    return violations


def imports_from(graph: dict[str, set[str]], package: str) -> list[str]:
    """Every import of `package` or a module in it, as readable lines."""
    return [
        f"{module} imports {imported}"
        for module, imports in sorted(graph.items())
        for imported in sorted(imports)
        if imported == package or imported.startswith(package + ".")
    ]


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected groups of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in graph[node]:
            if nxt not in graph:
                continue
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            group = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                group.append(member)
                if member == node:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def _write(root: Path, files: dict[str, str]) -> None:
    for relative, source in files.items():
        path = root / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(source)


def test_the_checker_catches_an_outward_import_a_training_import_and_a_cycle(
    tmp_path: Path,
) -> None:
    _write(
        tmp_path,
        {
            "service/__init__.py": "",
            "service/errors.py": "",
            "service/pipeline/__init__.py": "",
            "service/pipeline/run.py": "from service.models.registry import ServedModel\n",
            "service/pipeline/sampling.py": "def f():\n    import onnxruntime\n",
            "service/models/__init__.py": "",
            "service/models/registry.py": "from ..pipeline import run\n",
            "service/api/__init__.py": "",
            "service/api/smm.py": "import training.data\nfrom service.errors import X\n",
            "training/__init__.py": "",
            "training/cli.py": "from service.api import smm\nfrom training import train\n",
            "training/train.py": "def main():\n    from training.cli import go\n",
            "tools/__init__.py": "",
            "tools/check.py": "def main():\n    from tests.support import oracle\n",
            "tools/fine.py": "from training import train\nimport testsuite\n",
        },
    )
    graph = import_graph(tmp_path, ["service", "training"])
    assert "service.pipeline.run" in graph["service.models.registry"]  # relative import
    violations = direction_violations(graph)
    for expected in [
        "service.pipeline.run (pipeline) imports service.models.registry (models)",
        "service.pipeline.sampling (pipeline) imports onnxruntime",
        "service.api.smm imports training.data: service never imports training",
        "training.cli imports service.api.smm (edge)",
    ]:
        assert any(v.startswith(expected) for v in violations), (expected, violations)
    assert not any("service.errors" in v for v in violations)  # edge -> contract is fine
    assert ["service.models.registry", "service.pipeline.run"] in cycles(graph)
    assert ["training.cli", "training.train"] in cycles(graph)
    tools = import_graph(tmp_path, ["tools"])
    assert imports_from(tools, "tests") == [
        "tools.check imports tests.support",
        "tools.check imports tests.support.oracle",
    ]


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph(ROOT, ["service", "training"])


def test_every_service_module_belongs_to_a_layer(graph: dict[str, set[str]]) -> None:
    unplaced = [m for m in graph if m.startswith("service.") and layer_of(m) is None]
    assert unplaced == []


def test_imports_run_one_way(graph: dict[str, set[str]]) -> None:
    assert direction_violations(graph) == []


def test_the_client_imports_only_the_contract(graph: dict[str, set[str]]) -> None:
    allowed = {i for i, (name, _) in enumerate(SERVICE_LAYERS) if name in CLIENT_MAY_IMPORT}
    client = [m for m in graph if m == "service.client" or m.startswith("service.client.")]
    assert client, "no service.client modules found"
    outside = [
        f"{module} imports {imported}"
        for module in client
        for imported in sorted(graph[module])
        if (layer := layer_of(imported)) is not None and layer not in allowed
    ]
    assert outside == []


def test_no_import_cycle_in_service_or_training(graph: dict[str, set[str]]) -> None:
    assert cycles(graph) == []


# The connect stage's package: outside it, only the names of its __all__ are imported.
CONNECT = "service.pipeline.connect"
# Unit tests of the package's modules, which import them by design, and the docs test that
# reads module constants by module name, as the docs' `constant` blocks name them.
CONNECT_TESTS = ("tests.service.pipeline.connect", "tests.docs.test_topic_api")


def public_names(package_init: Path) -> set[str]:
    """The names in a package's `__all__` (read from its source, not imported)."""
    for node in ast.parse(package_init.read_text()).body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets
        ):
            return {ast.literal_eval(element) for element in node.value.elts}  # type: ignore[attr-defined]
    raise AssertionError(f"{package_init} has no __all__")


def private_imports(
    root: Path, packages: Iterable[str], package: str, public: set[str]
) -> list[str]:
    """Imports of `package` from modules outside it that reach past its public names: one
    of its modules, or a name not in `public`."""
    found = []
    for top in packages:
        for path in sorted((root / top).rglob("*.py")):
            module = module_name(path, root)
            if module == package or module.startswith(package + "."):
                continue
            if any(module == t or module.startswith(t + ".") for t in CONNECT_TESTS):
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names if a.name.startswith(package + ".")]
                    found += [f"{module} imports {name}" for name in names]
                elif isinstance(node, ast.ImportFrom) and node.module:
                    if node.module.startswith(package + "."):
                        found.append(f"{module} imports {node.module}")
                    elif node.module == package:
                        hidden = sorted(a.name for a in node.names if a.name not in public)
                        found += [f"{module} imports {package}.{name}" for name in hidden]
    return found


def test_the_connect_checker_catches_a_module_and_a_private_name(tmp_path: Path) -> None:
    _write(
        tmp_path,
        {
            "service/pipeline/connect/__init__.py": "from x import a\n__all__ = ['a']\n",
            "service/pipeline/connect/roadmap.py": "from service.pipeline.connect import b\n",
            "service/pipeline/run.py": "from service.pipeline.connect import a\n",
            "training/methods.py": "from service.pipeline.connect.roadmap import Roadmap\n",
            "tools/profile.py": "from service.pipeline.connect import a, b\n",
            "tests/x.py": "import service.pipeline.connect.trace.walk\n",
        },
    )
    public = public_names(tmp_path / "service/pipeline/connect/__init__.py")
    assert public == {"a"}
    found = private_imports(tmp_path, ["service", "training", "tools", "tests"], CONNECT, public)
    assert sorted(found) == [
        "tests.x imports service.pipeline.connect.trace.walk",
        "tools.profile imports service.pipeline.connect.b",
        "training.methods imports service.pipeline.connect.roadmap",
    ]


def test_code_outside_connect_imports_only_its_public_api() -> None:
    public = public_names(ROOT / "service/pipeline/connect/__init__.py")
    packages = ["service", "training", "tools", "tests"]
    assert private_imports(ROOT, packages, CONNECT, public) == []


def test_tools_import_nothing_from_tests() -> None:
    tools = import_graph(ROOT, ["tools"])
    assert "tools.container_test.targets" in tools
    assert imports_from(tools, "tests") == []


# training/sweep/: each module imports only those before it (its package docstring).
SWEEP_ORDER = ("plan", "measures", "rule", "reasons", "search", "command")


def test_the_sweep_package_imports_one_way(graph: dict[str, set[str]]) -> None:
    modules = [f"training.sweep.{name}" for name in SWEEP_ORDER]
    assert all(module in graph for module in modules)
    backwards = [
        f"{module} imports {imported}"
        for position, module in enumerate(modules)
        for imported in sorted(graph[module])
        if imported in modules[position:] or imported == "training.sweep"
    ]
    assert backwards == []
