"""The package's layers: commands (emgail_jax/*.py) over the host side (emgail_jax/host) over
the method (emgail_jax/method) over the envs; every import points down (README, "Where each
part of the paper lives"). Read from the source, so nothing is imported."""

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
COMMANDS = {
    "emgail_jax.run",
    "emgail_jax.train",
    "emgail_jax.evaluate",
    "emgail_jax.reoptimize",
    "emgail_jax.experts",
}
# What each layer may import from the project, besides itself.
ALLOWED = {
    "envs": ("envs",),
    "emgail_jax.method": ("envs", "emgail_jax.method"),
    "emgail_jax.host": ("envs", "emgail_jax.method", "emgail_jax.host", "emgail_jax"),
}


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


@pytest.mark.parametrize("layer", list(ALLOWED))
def test_imports_point_down_the_layers(layer):
    files = layer_files(layer)
    assert files, f"no modules in {layer}"
    upward = []
    for path in files:
        for name in project_imports(path):
            below = any(name == a or name.startswith(f"{a}.") for a in ALLOWED[layer])
            if not below or name in COMMANDS:
                upward.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not upward, "\n".join(upward)


def test_the_checker_sees_an_upward_import(tmp_path):
    module = tmp_path / "m.py"
    module.write_text("def f():\n    from emgail_jax.host.checkpoints import save\n")
    assert "emgail_jax.host.checkpoints" in project_imports(module)
