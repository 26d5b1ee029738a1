"""The library files each DVC stage imports, and dvc.yaml's code deps written from them.

    python tools/dvc_deps.py            # check: list every stage whose code deps differ (exit 1)
    python tools/dvc_deps.py --write    # rewrite dvc.yaml's code deps (and train_depth's per-variant items)

A stage's code deps are its script and every ``f2depth`` file the script reaches through imports: at module
level or inside a function, through package ``__init__`` files (importing ``f2depth.a.b`` runs
``f2depth/a/__init__.py``), never through imports under ``if TYPE_CHECKING:`` (they do not run).
``f2depth/__init__.py`` holds the version string only and is no dep. Each stage's deps list keeps its
data deps (datasets, models, the metrics a stage reads) and their comments first; the generated code deps
follow one marker comment. ``params`` moves above ``deps``, so that a stage opens with what a user edits.

train_depth's ``foreach`` items are written from params.yaml ``variants``: the flow model DVC tracks (the
stage script for a variant without one) and, per term of L_depth (``f2depth.train.step.TERMS``), the
weight's key it trains with (``lambda1``, ..., ``f2depth.train.step.WEIGHT_KEYS``), or its own
``variants.<name>`` entry for a term it trains without, so that ``dvc exp run -S lambda3=0`` retrains exactly
the variants that use L_feature.
"""

from __future__ import annotations

import ast
import re
import sys
from collections.abc import Iterable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE_ROOT = "f2depth/__init__.py"
MARKER = "# library files the script imports: written by tools/dvc_deps.py --write"
CODE_PREFIXES = ("stages/", "f2depth/")
KEY_ORDER = ("cmd", "params", "deps", "outs", "metrics", "plots")


# ---- the import graph -------------------------------------------------------------------------------


def module_file(name: str, root: Path = ROOT) -> Path | None:
    """The file of library module ``name`` (``f2depth.a.b``), or None when it is not one."""
    base = root.joinpath(*name.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def lazy_homes(package: str, root: Path = ROOT) -> dict[str, str]:
    """``_HOMES`` of a package whose ``__init__`` imports its names on first use (name → submodule)."""
    init = root.joinpath(*package.split("."), "__init__.py")
    if not init.is_file():
        return {}
    for node in ast.parse(init.read_text()).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "_HOMES" for t in node.targets):
            return ast.literal_eval(node.value)
    return {}


def imported_names(path: Path, root: Path = ROOT, type_checking: bool = False) -> set[str]:
    """Dotted names ``path`` imports where the import runs (``from f2depth.x import y`` gives ``f2depth.x``
    and ``f2depth.x.y``, or the submodule a lazy package's ``_HOMES`` names for ``y``), skipping the bodies
    of ``if TYPE_CHECKING:`` unless ``type_checking``."""
    names: set[str] = set()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _type_checking(child.test) and not type_checking:
                for other in child.orelse:
                    visit_node(other)
                continue
            visit_node(child)

    def visit_node(node: ast.AST) -> None:
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            homes = lazy_homes(node.module, root)
            names.update(f"{node.module}.{homes.get(alias.name, alias.name)}" for alias in node.names)
        visit(node)

    visit(ast.parse(path.read_text(), str(path)))
    return names


def imported_modules(path: Path, root: Path = ROOT) -> set[str]:
    """Library modules ``path`` imports, with the packages whose ``__init__`` the import runs."""
    found = set()
    for name in imported_names(path, root):
        parts = name.split(".")
        if parts[0] != "f2depth":
            continue
        prefixes = (".".join(parts[:i]) for i in range(1, len(parts) + 1))
        found.update(prefix for prefix in prefixes if module_file(prefix, root))
    return found


def closure(script: Path, root: Path = ROOT) -> set[Path]:
    """Every library file ``script`` reaches through imports that run."""
    seen: set[str] = set()
    todo = list(imported_modules(script, root))
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        todo.extend(imported_modules(module_file(name, root), root) - seen)
    return {module_file(name, root) for name in seen}


def code_deps(script: str, root: Path = ROOT) -> list[str]:
    """The code deps of a stage whose script is ``script`` (relative to ``root``): the script, then the
    library files it imports, sorted."""
    files = {p.relative_to(root).as_posix() for p in closure(root / script, root)} - {PACKAGE_ROOT}
    return [script, *sorted(files)]


# ---- dvc.yaml ---------------------------------------------------------------------------------------


def is_code(dep: str) -> bool:
    return dep.startswith(CODE_PREFIXES) and "${" not in dep


def stage_scripts(dvc_yaml: Path) -> dict[str, str]:
    """Stage name → its script (``python stages/<x>.py …`` in ``cmd``)."""
    spec = _load_yaml(dvc_yaml)["stages"]
    out = {}
    for name, stage in spec.items():
        body = stage.get("do", stage)
        out[name] = re.search(r"python (stages/\w+\.py)", body["cmd"]).group(1)
    return out


def declared_code_deps(dvc_yaml: Path) -> dict[str, list[str]]:
    """Stage name → the code deps dvc.yaml lists (files and folders under ``stages/`` and ``f2depth/``)."""
    spec = _load_yaml(dvc_yaml)["stages"]
    return {name: [d for d in stage.get("do", stage)["deps"] if is_code(d)] for name, stage in spec.items()}


def differences(root: Path = ROOT) -> list[str]:
    """One line per missing or superfluous code dep of a stage (empty: dvc.yaml is exact)."""
    declared = declared_code_deps(root / "dvc.yaml")
    out = []
    for name, script in stage_scripts(root / "dvc.yaml").items():
        want, have = code_deps(script, root), declared[name]
        out += [f"{name}: missing {d}" for d in want if d not in have]
        out += [f"{name}: superfluous {d}" for d in have if d not in want]
    return out


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip(" "))


def _blocks(lines: list[str], indent: int) -> list[tuple[str | None, list[str]]]:
    """Split a mapping's lines (keys at ``indent``) into (key, lines) blocks; comment lines go with the
    key that follows them."""
    blocks: list[tuple[str | None, list[str]]] = []
    pending: list[str] = []
    for line in lines:
        stripped = line.strip()
        if _indent(line) == indent and stripped and not stripped.startswith("#"):
            blocks.append((stripped.split(":", 1)[0], pending + [line]))
            pending = []
        elif blocks and (not stripped or stripped.startswith("#")) and _indent(line) <= indent:
            pending.append(line)
        elif blocks:
            blocks[-1][1].extend(pending + [line])
            pending = []
        else:
            pending.append(line)
    if pending:
        blocks.append((None, pending))
    return blocks


def _deps_block(block: list[str], indent: int, code: Iterable[str]) -> list[str]:
    """The ``deps:`` block with its data items (and their comments) kept, then the generated code deps."""
    head = [line for line in block if _indent(line) == indent and line.strip().startswith("deps:")]
    key_at = block.index(head[0])
    comments, body, kept, pending = block[:key_at], block[key_at + 1:], [], []
    item = " " * (indent + 2) + "- "
    for line in body:
        stripped = line.strip()
        if stripped.startswith("#"):
            pending.append(line)
        elif line.startswith(item):
            value = stripped[2:].split(" #")[0].strip()
            if not is_code(value):
                kept += pending + [line]
            pending = []
    code_lines = [" " * (indent + 2) + MARKER] + [f"{item}{d}" for d in code]
    return comments + [head[0]] + kept + code_lines


def _load_yaml(path: Path) -> dict:
    """A YAML file read as f2depth reads every YAML (f2depth.params.load_yaml: aliases that expand to a
    bomb are refused)."""
    sys.path.insert(0, str(ROOT))
    from f2depth.params import load_yaml

    return load_yaml(path.read_text())


def _variant_items(root: Path, indent: int) -> list[str]:
    """train_depth's ``foreach`` mapping from params.yaml ``variants``."""
    variants = _load_yaml(root / "params.yaml")["variants"]
    pad = " " * indent
    lines = [f"{pad}foreach:"]
    for name, v in variants.items():
        lines.append(f"{pad}  {name}:")
        lines.append(f"{pad}    flow: {v.get('flow') or 'stages/train_depth.py'}")
        for term, weight_key in _weight_keys(root).items():
            key = f"variants.{name}" if term in (v.get("without") or ()) else weight_key
            lines.append(f"{pad}    {term}: {key}")
    return lines


def _weight_keys(root: Path) -> dict[str, str]:
    """Each term of L_depth (in f2depth.train.step.TERMS's order) → the params key of its weight."""
    sys.path.insert(0, str(root))
    from f2depth.train.step import TERMS, WEIGHT_KEYS

    return {term: WEIGHT_KEYS[term] for term in TERMS}


def _term_params(block: list[str], root: Path) -> list[str]:
    """train_depth's ``params`` with one ``${item.<term>}`` per term of L_depth after ``variants.${key}``
    (the weights the variant trains with, named by its foreach item)."""
    kept = [line for line in block if "${item." not in line]
    at = next(i for i, line in enumerate(kept) if line.strip() == "- variants.${key}")
    pad = " " * _indent(kept[at])
    return kept[: at + 1] + [f"{pad}- ${{item.{t}}}" for t in _weight_keys(root)] + kept[at + 1:]


def rewrite(text: str, root: Path = ROOT) -> str:
    """dvc.yaml ``text`` with every stage's code deps generated, ``params`` before ``deps`` and
    train_depth's ``foreach`` items written from params.yaml."""
    scripts = stage_scripts(root / "dvc.yaml")
    lines = text.splitlines()
    start = lines.index("stages:") + 1
    end = next((i for i in range(start, len(lines)) if lines[i] and _indent(lines[i]) == 0
                and not lines[i].startswith("#")), len(lines))
    out = lines[:start]
    for name, block in _blocks(lines[start:end], 2):
        if name not in scripts:
            out += block
            continue
        at = next(i for i, line in enumerate(block)
                  if _indent(line) == 2 and not line.strip().startswith("#"))
        out += block[: at + 1] + _stage_body(name, block[at + 1:], scripts[name], root)
    return "\n".join(out + lines[end:]) + "\n"


def _stage_body(name: str, lines: list[str], script: str, root: Path) -> list[str]:
    blocks = _blocks(lines, 4)
    keys = [k for k, _ in blocks]
    if "do" in keys:
        out: list[str] = []
        for key, block in blocks:
            if key == "foreach" and name == "train_depth":
                comments = [x for x in block if x.strip().startswith("#") and _indent(x) == 4]
                out += comments + _variant_items(root, 4)
            elif key == "do":
                inner = _blocks(block[1:], 6)
                if name == "train_depth":
                    inner = [(k, _term_params(b, root) if k == "params" else b) for k, b in inner]
                out += [block[0]] + _ordered(inner, 6, script, root)
            else:
                out += block
        return out
    return _ordered(blocks, 4, script, root)


def _ordered(blocks: list[tuple[str | None, list[str]]], indent: int, script: str, root: Path) -> list[str]:
    rank = {k: i for i, k in enumerate(KEY_ORDER)}
    blocks = sorted(blocks, key=lambda b: rank.get(b[0], len(rank)))
    out: list[str] = []
    for key, block in blocks:
        out += _deps_block(block, indent, code_deps(script, root)) if key == "deps" else block
    return out


def main(argv: list[str]) -> int:
    path = ROOT / "dvc.yaml"
    if argv == ["--write"]:
        path.write_text(rewrite(path.read_text()))
        left = differences()
        print(f"wrote {path.relative_to(ROOT)}" + (f"; still differs: {left}" if left else ""))
        return 1 if left else 0
    if argv:
        print(__doc__.split("\n\n")[1])
        return 2
    left = differences()
    for line in left:
        print(line)
    if left:
        print("dvc.yaml's code deps differ from the imports: python tools/dvc_deps.py --write")
    return 1 if left else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
