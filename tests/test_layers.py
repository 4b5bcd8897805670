"""The layers of the house (docs/architecture.md), enforced from the import graph: imports only
point down, `jaxtrack` never imports `sims` or MuJoCo, and no module reaches into another
module's private names."""

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent

# Bottom to top; a module may import its own layer and the layers below it.
LAYERS = (
    ("_checks", "_gather", "angles", "geometry"),
    ("metrics",),
    ("models",),
    ("filters",),
    ("perception",),
    ("association",),
    ("tracking",),
    ("control",),
    ("montecarlo", "tuning"),
    ("io",),
    ("plotting", "demo"),
)
RANK = {name: i for i, names in enumerate(LAYERS) for name in names}
TOP = len(LAYERS)  # the `jaxtrack` package itself, which re-exports the layers


def _modules():
    for pkg in ("jaxtrack", "sims"):
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            yield ".".join(parts), path


def _is_module(name: str) -> bool:
    rel = pathlib.Path(*name.split("."))
    return (ROOT / rel).with_suffix(".py").exists() or (ROOT / rel / "__init__.py").exists()


def _imports(path):
    """(imported module names, private names reached into) of one file, including imports
    inside functions."""
    tree = ast.parse(path.read_text())
    modules, aliases, private = set(), {}, []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                modules.add(a.name)
                aliases[a.asname or a.name.split(".")[0]] = a.name
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for a in node.names:
                full = f"{node.module}.{a.name}"
                if _is_module(full):
                    modules.add(full)
                    aliases[a.asname or a.name] = full
                else:
                    modules.add(node.module)
                    if a.name.startswith("_") and node.module.split(".")[0] in ("jaxtrack",
                                                                                "sims"):
                        private.append(f"from {node.module} import {a.name}")
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id in aliases and node.attr.startswith("_")
                and not node.attr.startswith("__")
                and aliases[node.value.id].split(".")[0] in ("jaxtrack", "sims")
                and not _is_module(f"{aliases[node.value.id]}.{node.attr}")):
            private.append(f"{aliases[node.value.id]}.{node.attr}")
    return modules, private


def _rank(module: str):
    parts = module.split(".")
    if parts[0] == "sims":
        return TOP + 1
    if parts[0] != "jaxtrack":
        return None
    if len(parts) == 1:
        return TOP
    return RANK[parts[1]]


MODULES = list(_modules())


def test_every_jaxtrack_module_has_a_layer():
    for name, _ in MODULES:
        parts = name.split(".")
        if parts[0] == "jaxtrack" and len(parts) > 1:
            assert parts[1] in RANK, f"{name} is in no layer of LAYERS (docs/architecture.md)"


@pytest.mark.parametrize("name,path", MODULES, ids=[m for m, _ in MODULES])
def test_imports_point_down(name, path):
    mine = _rank(name)
    modules, _ = _imports(path)
    for target in modules:
        root = target.split(".")[0]
        if name.startswith("jaxtrack"):
            assert root not in ("sims", "mujoco"), f"{name} imports {target}"
        theirs = _rank(target)
        if theirs is None or (name.startswith("sims") and target.startswith("sims")):
            continue
        assert theirs <= mine, (f"{name} (layer {mine}) imports {target} (layer {theirs}): "
                                f"imports must point down")


@pytest.mark.parametrize("name,path", MODULES, ids=[m for m, _ in MODULES])
def test_no_module_reaches_into_another_modules_private_names(name, path):
    _, private = _imports(path)
    assert not private, f"{name} uses private names of other modules: {private}"


def test_the_checker_sees_a_violation():
    # The checks above must be able to fail: a synthetic module importing upward and reaching
    # into a private name is caught.
    src = ("from jaxtrack.control import follower\nfrom sims.following import episode\n"
           "x = follower._law\n")
    tmp = ROOT / ".pytest_cache" / "layer_probe.py"
    tmp.parent.mkdir(exist_ok=True)
    tmp.write_text(src)
    try:
        modules, private = _imports(tmp)
    finally:
        tmp.unlink()
    assert "sims.following.episode" in modules and private == ["jaxtrack.control.follower._law"]
    assert _rank("jaxtrack.metrics.errors") < _rank("jaxtrack.tracking.user") < _rank("sims")
