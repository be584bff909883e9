"""The shape of the package: which parts may import which, and no import circles.

Every ``import`` statement of every spcodec module counts, including those inside functions and
under ``TYPE_CHECKING``: a lazy import hides a circle from the interpreter but not from a reader,
who still cannot understand either module without the other.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"spcodec": "spcodec", "decoder": "spcodec.decoder", "encoder": "spcodec.encoder",
            "imaging": "spcodec.imaging", "conformance": "spcodec.conformance", "cli": "spcodec.cli",
            "tiling": "spcodec.tiling"}
"""Source folder -> the package it installs as (pyproject's package-dir)."""


def _modules() -> dict[str, Path]:
    found = {}
    for folder, package in PACKAGES.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = path.relative_to(ROOT / folder).with_suffix("").parts
            if "vectors" in parts:
                continue
            name = ".".join([package, *parts])
            found[name.removesuffix(".__init__")] = path
    return found


MODULES = _modules()


def _target(module: str, is_package: bool, node: ast.ImportFrom) -> str | None:
    if node.level == 0:
        return node.module
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(module: str, path: Path) -> set[str]:
    """The spcodec modules ``module`` imports (a name imported from a package counts as its
    submodule when one of that name exists)."""
    out: set[str] = set()
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _target(module, path.name == "__init__.py", node)
            if base is None:
                continue
            names = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base
                     for a in node.names]
        else:
            continue
        out.update(n for n in names if n in MODULES and n != module)
    return out


GRAPH = {name: _imports(name, path) for name, path in MODULES.items()}


def _reachable(start: str) -> set[str]:
    seen, todo = set(), [start]
    while todo:
        for nxt in GRAPH.get(todo.pop(), ()):
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def _parent_packages(name: str) -> set[str]:
    parts = name.split(".")
    return {".".join(parts[:i]) for i in range(1, len(parts))}


def test_the_graph_sees_the_packages():
    assert {"spcodec.encoder.pipeline", "spcodec.imaging.render.api", "spcodec.decoder.api",
            "spcodec.conformance.cases", "spcodec.cli.encode", "spcodec.cli.server"} <= set(MODULES)
    assert "spcodec.encoder.config" in GRAPH["spcodec.encoder.pipeline"]


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_module_imports_itself_back(module):
    """A module never reaches itself through its imports (a package's ``__init__`` re-exporting
    its own submodules is the one allowed loop: those submodules import siblings, not it)."""
    back = [m for m in GRAPH[module] if module in _reachable(m) and module not in
            _parent_packages(m)]
    assert not back, f"{module} imports {back}, which import it back"


def test_decoder_and_format_layer_never_reach_the_picture_tools_the_encoder_or_the_cli():
    """Every module of spcodec/ and decoder/ (the command line, which dispatches to the encoder,
    is its own package, cli/)."""
    folders = {name: path.relative_to(ROOT).parts[0] for name, path in MODULES.items()}
    light = [m for m, folder in folders.items() if folder in ("spcodec", "decoder")]
    assert "spcodec.decoder.api" in light and "spcodec.writer" in light and "spcodec" in light
    for module in light:
        heavy = {m for m in _reachable(module) if m.startswith(("spcodec.encoder",
                                                                 "spcodec.imaging", "spcodec.cli"))}
        assert not heavy, f"{module} reaches {sorted(heavy)}"


def test_picture_tools_never_import_the_encoder():
    """The encoder uses the picture tools, never the other way round."""
    for module in (m for m in MODULES if m.startswith("spcodec.imaging")):
        assert not {m for m in GRAPH[module] if m.startswith("spcodec.encoder")}, module


def test_encoder_configs_import_no_stage():
    assert not {m for m in _reachable("spcodec.encoder.config")
                if m.startswith("spcodec.encoder")}


def test_importing_the_picture_tools_package_loads_no_torch():
    code = ("import sys, spcodec.imaging, spcodec.imaging.cameras; "
            "sys.exit(1 if 'torch' in sys.modules else 0)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr


def test_cli_commands_share_only_the_common_modules():
    """A command module may use the shared ones (options, scenes) and serve its server, never
    another command: each reads on its own, and the package's ``__init__`` assembles them."""
    shared = {"spcodec.cli.options", "spcodec.cli.scenes", "spcodec.cli.server"}
    commands = [m for m in MODULES if m.startswith("spcodec.cli.") and m not in shared
                and m != "spcodec.cli.__main__"]
    assert {"spcodec.cli.decode", "spcodec.cli.encode", "spcodec.cli.serve"} <= set(commands)
    for module in commands:
        used = {m for m in GRAPH[module] if m.startswith("spcodec.cli")}
        assert used <= shared, f"{module} imports {sorted(used - shared)}"
