"""dvc.yaml declares, for every stage, every library module its script imports (directly or through other
library modules, at module level or inside a function): a change to any of them re-runs the stage."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


def module_file(name: str) -> Path | None:
    """The file of library module ``name`` (``f2depth.a.b``), or None when it is not one."""
    base = ROOT.joinpath(*name.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def lazy_homes(package: str) -> dict[str, str]:
    """``_HOMES`` of a package whose ``__init__`` imports its names on first use (name → submodule)."""
    init = ROOT.joinpath(*package.split("."), "__init__.py")
    if not init.is_file():
        return {}
    for node in ast.parse(init.read_text()).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "_HOMES" for t in node.targets):
            return ast.literal_eval(node.value)
    return {}


def imported_modules(path: Path) -> set[str]:
    """Library modules ``path`` imports (``from f2depth.x import y`` counts ``f2depth.x.y`` when y is one)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            homes = lazy_homes(node.module)
            names.update(f"{node.module}.{homes.get(alias.name, alias.name)}" for alias in node.names)
    found = set()
    for name in names:
        if name.split(".")[0] != "f2depth":
            continue
        parts = name.split(".")
        # importing f2depth.a.b runs f2depth/__init__ and f2depth/a/__init__ too
        prefixes = (".".join(parts[:i]) for i in range(1, len(parts) + 1))
        found.update(prefix for prefix in prefixes if module_file(prefix))
    return found


def closure(script: Path) -> set[Path]:
    """Every library file ``script`` reaches through imports."""
    seen: set[str] = set()
    todo = list(imported_modules(script))
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        todo.extend(imported_modules(module_file(name)) - seen)
    return {module_file(name) for name in seen}


def covered(path: Path, deps: list[str]) -> bool:
    rel = path.relative_to(ROOT).as_posix()
    return any(rel == dep or rel.startswith(dep.rstrip("/") + "/") for dep in deps)


def stages() -> list[tuple[str, Path, list[str]]]:
    spec = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    out = []
    for name, stage in spec.items():
        body = stage.get("do", stage)
        script = re.search(r"python (stages/\w+\.py)", body["cmd"]).group(1)
        deps = [d for d in body["deps"] if "${" not in d]
        out.append((name, ROOT / script, deps))
    return out


def test_the_checker_follows_imports_inside_functions_and_packages(tmp_path):
    script = tmp_path / "s.py"
    script.write_text("def main():\n    from f2depth.train.run import run_variant\n")
    files = {p.relative_to(ROOT).as_posix() for p in closure(script)}
    assert {"f2depth/__init__.py", "f2depth/train/__init__.py", "f2depth/train/run.py",
            "f2depth/geometry.py"} <= files
    assert not covered(ROOT / "f2depth/eval/scoring.py", ["f2depth/eval/nyu.py", "f2depth/train"])
    assert covered(ROOT / "f2depth/eval/scoring.py", ["f2depth/eval"])
    lazy = tmp_path / "lazy.py"
    lazy.write_text("from f2depth.keypoints import KeypointFile\n")
    assert ROOT / "f2depth/keypoints/store.py" in closure(lazy)  # a name the package imports on first use


def test_every_stage_declares_the_library_modules_it_imports():
    listed = stages()
    assert len(listed) >= 10
    package_root = ROOT / "f2depth/__init__.py"  # the version string only: no stage lists it
    assert not imported_modules(package_root)
    missing = []
    for name, script, deps in listed:
        assert script.relative_to(ROOT).as_posix() in deps, f"{name}: its script is not a dep"
        for path in sorted(closure(script)):
            if path != package_root and not covered(path, deps):
                missing.append(f"{name}: {path.relative_to(ROOT).as_posix()}")
    assert not missing, "add to the stage's deps in dvc.yaml:\n  " + "\n  ".join(missing)
