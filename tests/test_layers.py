"""The library's layers (CONTRIBUTING.md, "Layers"): a package imports only from its own package and from
packages of lower layers, never from a later part of the pipeline, and no modules import each other in a
circle. So an edit re-runs only the DVC stages below it in the pipeline, and tools/dvc_deps.py's exact
deps stay short."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
import dvc_deps  # noqa: E402

LAYERS: tuple[tuple[str, ...], ...] = (
    ("threads",),  # the CPUs a process may use (the process pools of `workers` keep to them)
    # primitives: numbers, files, parameters, geometry, cameras, tracking, superpixels, the errors
    ("numbers", "io", "params", "precision", "workers", "processes", "data_parallel", "tracking", "colour",
     "geometry", "camera", "superpixels", "signals", "errors", "lazy"),
    ("epochs", "profile", "averaging"),  # the one training-loop skeleton, profiling, weight averaging
    ("formats",),  # the on-disk formats: every dataset's reader/writer and the prepared set's
    ("synth",),  # the embedded synthetic world
    ("ingest",),  # your own video → raw frames
    ("data",),  # the prepare stage
    ("keypoints",),  # DSO's selector
    ("poses",),  # multi-view poses
    ("flow",),  # PWC-Lite, its pretraining (and its generated pairs) and fine-tuning
    ("losses", "depth"),  # the terms of L_depth; DepthCNN and PoseCNN, running them for evaluation
    ("protocols",),  # the test sets' evaluation protocols and metrics (training validates with NYU's)
    ("train",),  # depth training
    ("eval",),  # the evaluate stage: every protocol over a trained model, timing
    ("report",),  # the tables and figures, the paper's published numbers
    ("inference",),  # predict, export, reconstruct
    ("cli", "stage"),  # entry points
)  # fmt: skip


def package_of(path: Path, root: Path) -> str:
    rel = path.relative_to(root / "f2depth").with_suffix("")
    return rel.parts[0]


def edges(root: Path, type_checking: bool) -> dict[str, set[str]]:
    """Module → the library modules it imports (``f2depth.a.b`` names)."""
    out: dict[str, set[str]] = {}
    for path in sorted((root / "f2depth").rglob("*.py")):
        rel = path.relative_to(root).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
        name = ".".join(parts)
        found = set()
        for imported in dvc_deps.imported_names(path, root, type_checking=type_checking):
            while imported.count(".") and not dvc_deps.module_file(imported, root):
                imported = imported.rsplit(".", 1)[0]
            if imported.startswith("f2depth.") and imported != name:
                found.add(imported)
        out[name] = found
    return out


def layer_violations(root: Path) -> list[str]:
    """Imports (type-only ones too) into the same or a higher layer's other package."""
    rank = {pkg: i for i, layer in enumerate(LAYERS) for pkg in layer}
    out = []
    for module, imported in edges(root, type_checking=True).items():
        if module == "f2depth":
            continue
        src = module.split(".")[1]
        if src not in rank:
            out.append(f"{module}: package {src!r} is in no layer (tests/test_layers.py LAYERS)")
            continue
        for target in sorted(imported):
            dst = target.split(".")[1]
            if dst != src and rank.get(dst, len(LAYERS)) >= rank[src]:
                out.append(f"{module} imports {target}: {dst!r} is not below {src!r}")
    return out


def cycles(root: Path) -> list[list[str]]:
    """Circles of modules importing each other (imports that run)."""
    graph = edges(root, type_checking=False)
    found, state = [], {}

    def visit(node: str, path: list[str]) -> None:
        state[node] = "open"
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                found.append(path[path.index(nxt):] + [nxt] if nxt in path else [node, nxt])
            elif nxt not in state:
                visit(nxt, [*path, nxt])
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    return found


def test_every_package_imports_only_from_lower_layers():
    assert layer_violations(ROOT) == []


def test_no_modules_import_each_other_in_a_circle():
    assert cycles(ROOT) == []


def test_every_library_package_has_a_layer():
    packages = {p.stem if p.is_file() else p.name for p in (ROOT / "f2depth").iterdir()
                if (p.suffix == ".py" and p.stem != "__init__") or (p / "__init__.py").is_file()}
    assert packages == {pkg for layer in LAYERS for pkg in layer}


def test_a_planted_upward_import_and_a_planted_circle_are_found(tmp_path):
    (tmp_path / "f2depth").symlink_to(ROOT / "f2depth")
    assert layer_violations(tmp_path) == [] and cycles(tmp_path) == []
    fake = tmp_path / "fake"
    for pkg in ("data", "eval"):
        (fake / "f2depth" / pkg).mkdir(parents=True)
        (fake / "f2depth" / pkg / "__init__.py").write_text("")
    (fake / "f2depth" / "__init__.py").write_text("")
    (fake / "f2depth/data/loader.py").write_text("from f2depth.eval.suite import compute\n")
    (fake / "f2depth/eval/suite.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from f2depth.eval.timing import S\n"
        "def compute():\n    from f2depth.data.loader import x\n")
    (fake / "f2depth/eval/timing.py").write_text("from f2depth.eval import suite\n")
    assert layer_violations(fake) == [
        "f2depth.data.loader imports f2depth.eval.suite: 'eval' is not below 'data'"]
    assert cycles(fake) == [["f2depth.data.loader", "f2depth.eval.suite", "f2depth.data.loader"]]
