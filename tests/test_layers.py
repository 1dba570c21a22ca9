"""The package's layers: commands (emgail_jax/*.py) over the host side (emgail_jax/host) over
the method (emgail_jax/method) over the envs; every import points down (README, "Where each
part of the paper lives"), and no module reaches itself through its imports. Read from the
source, so nothing is imported."""

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
COMMANDS = {
    "emgail_jax.run",
    "emgail_jax.train",
    "emgail_jax.evaluate",
    "emgail_jax.reoptimize",
    "emgail_jax.refit",
    "emgail_jax.experts",
}
# What each layer may import from the project, besides itself.
ALLOWED = {
    "envs": ("envs",),
    "emgail_jax.method": ("envs", "emgail_jax.method"),
    "emgail_jax.host": ("envs", "emgail_jax.method", "emgail_jax.host", "emgail_jax"),
    "emgail_jax.reward": ("envs", "emgail_jax.method", "emgail_jax.host", "emgail_jax"),
}
# What a layer may not import although ALLOWED lets it: the host side runs runs, and the
# reward package builds on it.
FORBIDDEN = {"emgail_jax.host": ("emgail_jax.reward",)}


def project_imports(path: pathlib.Path) -> set[str]:
    """Every project module ``path`` imports, at any depth (lazy imports count too)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return {n for n in names if n.split(".")[0] in ("envs", "emgail_jax")}


def layer_files(layer: str) -> list[pathlib.Path]:
    return sorted((ROOT / layer.replace(".", "/")).glob("*.py"))


def _within(name: str, layers) -> bool:
    return any(name == a or name.startswith(f"{a}.") for a in layers)


@pytest.mark.parametrize("layer", list(ALLOWED))
def test_imports_point_down_the_layers(layer):
    files = layer_files(layer)
    assert files, f"no modules in {layer}"
    upward = []
    for path in files:
        for name in project_imports(path):
            allowed = _within(name, ALLOWED[layer]) and not _within(name, FORBIDDEN.get(layer, ()))
            if not allowed or name in COMMANDS:
                upward.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not upward, "\n".join(upward)


def import_circles(root: pathlib.Path, packages=("emgail_jax", "envs")) -> list[str]:
    """Every project module under ``root`` that reaches itself through its imports."""
    modules = {}
    for package in packages:
        for path in (root / package).rglob("*.py"):
            parts = path.relative_to(root).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    graph = {
        name: {n for n in project_imports(path) if n in modules and n != name}
        for name, path in modules.items()
    }
    circles = []
    for name in sorted(modules):
        seen, stack = set(), list(graph[name])
        while stack:
            module = stack.pop()
            if module not in seen:
                seen.add(module)
                stack.extend(graph[module])
        if name in seen:
            circles.append(name)
    return circles


def test_no_module_imports_itself_through_others():
    assert not import_circles(ROOT), "modules in an import circle: " + ", ".join(
        import_circles(ROOT)
    )


def test_the_checker_sees_an_import_circle(tmp_path):
    (tmp_path / "envs").mkdir()
    (tmp_path / "envs" / "a.py").write_text("import envs.b\n")
    (tmp_path / "envs" / "b.py").write_text("def f():\n    from envs.a import g\n")
    (tmp_path / "envs" / "c.py").write_text("import envs.a\n")
    assert import_circles(tmp_path, ("envs",)) == ["envs.a", "envs.b"]


def test_the_checker_sees_an_upward_import(tmp_path):
    module = tmp_path / "m.py"
    module.write_text("def f():\n    from emgail_jax.host.checkpoints import save\n")
    assert "emgail_jax.host.checkpoints" in project_imports(module)
