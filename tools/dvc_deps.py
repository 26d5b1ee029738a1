"""The library files each DVC stage imports, and dvc.yaml's code deps written from them.

    python tools/dvc_deps.py            # check: list every stage whose code deps differ (exit 1)
    python tools/dvc_deps.py --write    # rewrite dvc.yaml's code deps (and train_depth's per-variant items)

A stage's code deps are its script and every ``f2depth`` file the script reaches through imports: at module
level or inside a function, through package ``__init__`` files (importing ``f2depth.a.b`` runs
``f2depth/a/__init__.py``), never through imports under ``if TYPE_CHECKING:`` (they do not run).
``f2depth/__init__.py`` holds the version string only and is no dep.

Each stage's ``params`` and ``deps`` are written as flow lists (``deps: [...]``): the data deps (datasets,
models, the metrics a stage reads) in their order, then the script, then the library files, sorted, with each
folder whose every file the script imports written once as the folder (``f2depth/train/``; .dvcignore keeps
``__pycache__`` out of DVC's hash). A folder with one file the script does not import is listed file by file,
so that a new module re-runs no stage until one imports it. Comments of the two blocks go above their key;
``params`` moves above ``deps``, so that a stage opens with what a user edits.

train_depth's ``foreach`` items are written from params.yaml ``variants``: the flow model DVC tracks (the
stage script for a variant without one) and, per term of L_depth (``f2depth.train.step.TERMS``), the
weight's key it trains with (``lambda1``, ..., ``f2depth.train.step.WEIGHT_KEYS``), or its own
``variants.<name>`` entry for a term it trains without, so that ``dvc exp run -S lambda3=0`` retrains exactly
the variants that use L_feature.
"""

from __future__ import annotations

import ast
import json
import re
import sys
from collections.abc import Iterable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE_ROOT = "f2depth/__init__.py"
WIDTH = 120  # the flow lists' line length
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


def files_under(folder: Path, root: Path = ROOT) -> set[str]:
    """Every file DVC hashes for a folder dep (.dvcignore leaves out ``__pycache__``), relative to root."""
    return {p.relative_to(root).as_posix() for p in folder.rglob("*")
            if p.is_file() and "__pycache__" not in p.relative_to(folder).parts}


def folded(files: Iterable[str], root: Path = ROOT) -> list[str]:
    """``files`` with each folder below ``f2depth/`` whose every file is among them written once, as the
    folder (``f2depth/train/``): the outermost such folder, sorted with the single files."""
    have, covered, entries = set(files), set(), []
    folders = {Path(f).parent.as_posix() for f in have if f.startswith("f2depth/")}
    folders |= {p.as_posix() for f in folders for p in Path(f).parents}
    for folder in sorted(folders - {"f2depth", "."}, key=lambda f: (f.count("/"), f)):
        members = files_under(root / folder, root)
        if not covered >= members and members <= have:
            entries.append(folder + "/")
            covered |= members
    return sorted(entries + [f for f in have if f not in covered])


def expanded(dep: str, root: Path = ROOT) -> set[str]:
    """The files a code dep stands for: a folder's files, or the file itself."""
    return files_under(root / dep, root) if (root / dep).is_dir() else {dep.rstrip("/")}


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
    """One line per missing or superfluous code dep of a stage (empty: dvc.yaml is exact). A folder is
    superfluous when it holds a file the script does not import."""
    declared = declared_code_deps(root / "dvc.yaml")
    out = []
    for name, script in stage_scripts(root / "dvc.yaml").items():
        want = code_deps(script, root)
        have = set().union(*(expanded(d, root) for d in declared[name]))
        out += [f"{name}: missing {d}" for d in want if d not in have]
        for dep in declared[name]:
            extra = sorted(expanded(dep, root) - set(want))
            if extra:
                out.append(f"{name}: superfluous {dep}" + (f" (holds {', '.join(extra)})"
                                                           if (root / dep).is_dir() else ""))
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


def _token(value: str) -> str:
    """``value`` as an item of a YAML flow list: plain when it can be, else double-quoted."""
    if not isinstance(value, str):
        raise SystemExit(f"dvc.yaml: {value!r} is not a path or a params key: write it as one")
    return value if re.fullmatch(r"[\w./@-]+", value) else json.dumps(value, ensure_ascii=False)


def _flow_list(key: str, groups: list[list[str]], indent: int) -> list[str]:
    """``key: [a, b, ...]`` wrapped at WIDTH, each group of items starting a new line."""
    pad = " " * indent
    lines, line = [], f"{pad}{key}: ["
    tokens = [(i == 0, _token(v)) for group in groups for i, v in enumerate(group)]
    for n, (starts_group, token) in enumerate(tokens):
        piece = token + ("]" if n == len(tokens) - 1 else ",")
        fresh = line.endswith("[")
        if not fresh and (starts_group or len(line) + 1 + len(piece) > WIDTH):
            lines.append(line)
            line = pad + "  " + piece
        else:
            line += ("" if fresh else " ") + piece
    return lines + [line if tokens else f"{pad}{key}: []"]


def _comments(block: list[str], indent: int) -> list[str]:
    """A block's comment lines, indented to go above its key."""
    return [" " * indent + line.strip() for line in block if line.strip().startswith("#")]


def _load_yaml(path: Path) -> dict:
    return _parse(path.read_text())


def _variant_items(root: Path, indent: int) -> list[str]:
    """train_depth's ``foreach`` mapping from params.yaml ``variants``, one flow mapping a variant."""
    variants = _load_yaml(root / "params.yaml")["variants"]
    pad = " " * indent
    lines = [f"{pad}foreach:"]
    for name, v in variants.items():
        items = {"flow": v.get("flow") or "stages/train_depth.py"}
        for term, weight_key in _weight_keys(root).items():
            items[term] = f"variants.{name}" if term in (v.get("without") or ()) else weight_key
        pairs = [f"{k}: {_token(x)}" for k, x in items.items()]
        line = f"{pad}  {name}: {{" + ", ".join(pairs) + "}"
        if len(line) > WIDTH:  # the weights on a line of their own
            line = f"{pad}  {name}: {{{pairs[0]},\n{pad}    " + ", ".join(pairs[1:]) + "}"
        lines.append(line)
    return lines


def _weight_keys(root: Path) -> dict[str, str]:
    """Each term of L_depth (in f2depth.train.step.TERMS's order) → the params key of its weight."""
    sys.path.insert(0, str(root))
    from f2depth.train.step import TERMS, WEIGHT_KEYS

    return {term: WEIGHT_KEYS[term] for term in TERMS}


def _term_params(params: list[str], root: Path) -> list[str]:
    """train_depth's ``params`` with one ``${item.<term>}`` per term of L_depth after ``variants.${key}``
    (the weights the variant trains with, named by its foreach item)."""
    kept = [p for p in params if not str(p).startswith("${item.")]
    at = kept.index("variants.${key}") + 1
    return kept[:at] + [f"${{item.{t}}}" for t in _weight_keys(root)] + kept[at:]


def rewrite(text: str, root: Path = ROOT) -> str:
    """dvc.yaml ``text`` with every stage's ``params`` and ``deps`` written as flow lists (the deps: data,
    then the script and the library it imports, folded), ``params`` before ``deps`` and train_depth's
    ``foreach`` items written from params.yaml."""
    scripts = stage_scripts(root / "dvc.yaml")
    spec = _parse(text)["stages"]
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
        body = spec[name].get("do", spec[name])
        out += block[: at + 1] + _stage_body(name, block[at + 1:], scripts[name], body, root)
    return "\n".join(out + lines[end:]) + "\n"


def _parse(text: str) -> dict:
    """YAML text read as f2depth reads every YAML (f2depth.params.load_yaml: aliases that expand to a bomb
    are refused)."""
    sys.path.insert(0, str(ROOT))
    from f2depth.params import load_yaml

    return load_yaml(text)


def _stage_body(name: str, lines: list[str], script: str, body: dict, root: Path) -> list[str]:
    blocks = _blocks(lines, 4)
    if "do" not in [k for k, _ in blocks]:
        return _ordered(name, blocks, 4, script, body, root)
    out: list[str] = []
    for key, block in blocks:
        if key == "foreach" and name == "train_depth":
            out += _comments(block, 4) + _variant_items(root, 4)
        elif key == "do":
            out += [block[0]] + _ordered(name, _blocks(block[1:], 6), 6, script, body, root)
        else:
            out += block
    return out


def _ordered(name: str, blocks: list[tuple[str | None, list[str]]], indent: int, script: str, body: dict,
             root: Path) -> list[str]:
    rank = {k: i for i, k in enumerate(KEY_ORDER)}
    out: list[str] = []
    for key, block in sorted(blocks, key=lambda b: rank.get(b[0], len(rank))):
        if key == "params":
            params = _term_params(body["params"], root) if name == "train_depth" else body["params"]
            out += _comments(block, indent) + _flow_list("params", [params], indent)
        elif key == "deps":
            data = [d for d in body["deps"] if not is_code(d)]
            code = code_deps(script, root)
            groups = [data + code[:1], folded(code[1:], root)]
            out += _comments(block, indent) + _flow_list("deps", groups, indent)
        else:
            out += block
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
