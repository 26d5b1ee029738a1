"""Reading ``params.yaml``: stage scripts take their section from here and nothing else.

``section(params, "poses", PosesConfig)`` maps a section onto a frozen dataclass by its annotations, and
``value(params, "seed", int)`` reads one key; both raise :class:`ParamsError` with one line naming the file,
the dotted key and what is expected.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import operator
import os
import re
import types
import typing
from pathlib import Path
from typing import Any

import yaml

DEFAULT_PARAMS = Path("params.yaml")


class ParamsError(ValueError):
    """A parameter is missing or has a wrong value; the message names the key and the file."""


class _DuplicateKey(Exception):
    def __init__(self, key: Any, first: int, second: int) -> None:
        super().__init__(key, first, second)
        self.key, self.first, self.second = key, first, second


#: The most values (scalars, lists and mappings, each alias counted as what it stands for) a YAML document
#: f2depth reads may expand to: params.yaml has about 500, dvc.yaml about 1000. A "billion laughs" file of
#: 22 KB (aliases of aliases) expands to billions, and whatever walks it (a message, MLflow's log_params,
#: json) takes gigabytes.
MAX_YAML_VALUES = 100_000
#: Values quoted in messages are cut to this many characters (:func:`short`), whole error lines to MAX_LINE.
MAX_QUOTED, MAX_LINE = 240, 1000  # a long path stays whole; a 34 MB value does not


class YamlBomb(yaml.YAMLError):
    """A YAML document whose aliases expand beyond :data:`MAX_YAML_VALUES` values, or refer to themselves;
    ``problem`` says which, ``problem_mark`` where."""

    def __init__(self, problem: str, mark: Any = None) -> None:
        super().__init__(problem)
        self.problem, self.problem_mark = problem, mark


def expanded_values(node: yaml.Node, limit: int = MAX_YAML_VALUES) -> int:
    """How many values the composed YAML ``node`` stands for once every alias is expanded (a scalar is 1, a
    list or mapping 1 + its items'); each distinct node is counted once, so a bomb costs its file's size.
    More than ``limit``, or a node inside itself → :class:`YamlBomb`."""
    sizes: dict[int, int] = {}
    on_path: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(node, False)]
    while stack:
        current, done = stack.pop()
        key = id(current)
        if done:
            on_path.discard(key)
            children = _children(current)
            sizes[key] = 1 + sum(sizes[id(c)] for c in children)
            if sizes[key] > limit:
                raise YamlBomb(f"its aliases (*name) expand to more than {limit} values, a 'billion laughs' "
                               "bomb; write the values out", current.start_mark)
            continue
        if key in sizes:
            continue
        if key in on_path:
            raise YamlBomb("an alias (*name) refers to the value it is in", current.start_mark)
        on_path.add(key)
        stack.append((current, True))
        stack.extend((c, False) for c in _children(current) if id(c) not in sizes)
    return sizes[id(node)]


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


class BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader for every YAML file f2depth reads (params files, camera files, dvc.yaml): a
    document whose aliases expand beyond :data:`MAX_YAML_VALUES` values or refer to themselves is refused
    (:class:`YamlBomb`) before anything is built from it."""

    def construct_document(self, node: yaml.Node) -> Any:
        expanded_values(node)
        return super().construct_document(node)


def load_yaml(text: str | Any, loader: type[yaml.SafeLoader] = BoundedLoader) -> Any:
    """YAML text (or an open file) → Python values with :class:`BoundedLoader` (or a subclass ``loader``);
    raises ``yaml.YAMLError`` (:class:`YamlBomb` for a bomb)."""
    return yaml.load(text, Loader=loader)  # noqa: S506 - a SafeLoader subclass


def clip(text: str, limit: int = MAX_QUOTED) -> str:
    """``text`` cut to at most ``limit`` characters (with "…") for a message."""
    return text if len(text) <= limit else text[:limit - 1] + "…"


def short(value: Any, limit: int = MAX_QUOTED) -> str:
    """``repr(value)`` for a message, at most ``limit`` characters (cut with "…"); never builds the whole
    repr of a huge value."""
    import reprlib

    cut = reprlib.Repr()
    cut.fillvalue = "…"  # Python ≥ 3.11 (3.10 writes "...")
    cut.maxstring = cut.maxother = limit
    cut.maxlist = cut.maxtuple = cut.maxdict = cut.maxset = 8
    cut.maxlevel = 3
    return clip(cut.repr(value), limit)


class _UniqueKeyLoader(BoundedLoader):
    """:class:`BoundedLoader`, except that a key given twice in one mapping is an error (PyYAML keeps the
    last one silently; DVC refuses the file). Merge keys (``<<``) may still be overridden."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
                continue
            key = self.construct_object(key_node)
            line = key_node.start_mark.line + 1
            if key in seen:
                raise _DuplicateKey(key, seen[key], line)
            seen[key] = line
        return super().construct_mapping(node, deep=deep)


def load(path: str | os.PathLike = DEFAULT_PARAMS) -> dict[str, Any]:
    """The parameter file as a dict (``_file`` added: its path, for messages). A missing file, a YAML
    error or a key given twice in one section is a :class:`ParamsError` naming the file (and the lines)."""
    p = Path(path)
    if not p.is_file():
        raise ParamsError(f"{p}: parameter file not found (run from the repository root or pass its path)")
    with p.open() as fh:
        try:
            data = load_yaml(fh, _UniqueKeyLoader) or {}
        except _DuplicateKey as dup:
            raise ParamsError(f"{p}: key '{dup.key}' is given twice, on lines {dup.first} and {dup.second} "
                              "(YAML would keep the second silently, DVC refuses the file); keep one"
                              ) from None
        except YamlBomb as bomb:
            mark = bomb.problem_mark
            where = f" line {mark.line + 1}" if mark is not None else ""
            raise ParamsError(f"{p}:{where}: {bomb.problem}") from None
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f" line {mark.line + 1}" if mark is not None else ""
            problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
            raise ParamsError(f"{p}:{where} is not valid YAML ({problem}); fix the file") from None
    if not isinstance(data, dict):
        raise ParamsError(f"{p}: expected a mapping at the top level")
    data["_file"] = str(p)
    return data


def get(params: dict[str, Any], dotted: str, default: Any = ...) -> Any:
    """``get(p, "train_depth.epochs")``; raises :class:`ParamsError` naming the key when absent."""
    node: Any = params
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            if default is not ...:
                return default
            raise ParamsError(f"{params.get('_file', 'params.yaml')}: missing parameter '{dotted}'")
        node = node[part]
    return node


#: The one device grammar, of params.yaml's ``device`` and of the CLI's ``--device``.
DEVICES = "auto, cpu, cuda, cuda:N or mps"
_DEVICE = re.compile(r"auto|cpu|mps|cuda(:\d+)?")


def device_problem(name: str) -> str | None:
    """Why ``name`` is no device of this machine (one line, ending in the fix), or None when it is one:
    the grammar :data:`DEVICES`, then what this machine's torch offers (CUDA and its device count, mps)."""
    if not _DEVICE.fullmatch(name):
        return f"unknown device {short(name)}: use {DEVICES}"
    if name in ("auto", "cpu"):
        return None
    import torch

    if name == "mps":
        available = torch.backends.mps.is_available()
        return None if available else "mps (Apple GPU) is not available here; use cpu or auto"
    if not torch.cuda.is_available():
        return f"{name}: CUDA is not available (torch {torch.__version__} sees no GPU); use cpu or auto"
    count = torch.cuda.device_count()
    index = int(name.partition(":")[2] or 0)
    if index >= count:
        return f"{name}: this machine has {count} CUDA device(s), cuda:0..cuda:{count - 1}"
    return None


def resolve_device(name: str) -> str:
    """``auto`` → ``cuda`` when available else ``cpu``; any other device of the grammar is returned as given
    when this machine has it, else :class:`ParamsError` with :func:`device_problem`'s line."""
    problem = device_problem(name)
    if problem is not None:
        raise ParamsError(problem)
    if name == "auto":
        import torch

        return "cuda" if torch.cuda.is_available() else "cpu"
    return name


# ---- the one loader: a params section → a frozen dataclass -------------------------------------------

class Device(str):
    """Annotation of a device key: one of :data:`DEVICES` (the grammar checked by the loader; whether the
    machine has it, by :func:`resolve_device`)."""


#: Range rules a dataclass field may declare in its metadata, e.g. ``field(metadata={"min": 1})``.
RULES = {"min": (operator.ge, "a value >= {}"), "max": (operator.le, "a value <= {}"),
         "gt": (operator.gt, "a value > {}"), "multiple_of": (lambda v, m: v % m == 0, "a multiple of {}")}


def section(params: dict[str, Any], key: str, cls: type, *more: type, **given: Any) -> Any:
    """The params section ``key`` (dotted) as an instance of the frozen dataclass ``cls``.

    Every key of the section must be a field of ``cls`` (or of one of ``more``: a section shared by a library
    config and a stage's own keys; a tuple of instances is then returned), and every field must be in the
    section or in ``given`` (values from elsewhere: a CLI flag, a top-level key); params.yaml is the one
    source of defaults, so a dataclass default never stands in for a missing key (except for a field marked
    ``field(metadata={"fixed": True})``: a constant of the method, not a parameter). Values are checked
    against the field's type (:func:`value`) and its metadata rules (:data:`RULES`); a ``__post_init__``
    ValueError or TypeError becomes a ParamsError too, under ``key.field`` when its message starts with a
    field's name. Every error is one line naming the file and the dotted key.
    """
    node = get(params, key)
    out = _build(_file(params), key, node, (cls, *more), given)
    return tuple(out) if more else out[0]


def value(params: dict[str, Any], key: str, kind: Any, **rules: Any) -> Any:
    """The params value ``key`` (dotted) checked against the type ``kind`` and :data:`RULES`
    (``value(p, "train_depth.epochs", int, min=1)``)."""
    return _check(_file(params), key, get(params, key), kind, rules)


def device(params: dict[str, Any]) -> str:
    """The ``device`` key, checked (:class:`Device`) and resolved (:func:`resolve_device`)."""
    name = value(params, "device", Device)
    try:
        return resolve_device(name)
    except ParamsError as exc:
        raise ParamsError(f"{_file(params)}: {exc}") from None


def threads(params: dict[str, Any]) -> int | None:
    """The ``threads`` key: torch's and OpenCV's thread budget (null: f2depth.threads chooses)."""
    return value(params, "threads", int | None, min=1)


def reject_unknown(path: str | os.PathLike, key: str, names: Any, known: Any, what: str = "keys") -> None:
    """Raise :class:`ParamsError` when ``names`` (the keys, or with ``what`` another word the entries, of the
    params value ``key``) has any that is not in ``known``: one line with a did-you-mean hint for each close
    match, else the known names."""
    known = [str(k) for k in known]
    unknown = sorted({str(n) for n in names} - set(known))
    if not unknown:
        return
    where = (lambda k: f"{key}.{k}") if what == "keys" else repr
    hints = [f"{where(k)}: did you mean {m[0]}?" for k in unknown
             if (m := difflib.get_close_matches(k, known, n=1))]
    raise ParamsError(f"{path}: {key}: unknown {what} {unknown}" + "".join(f"; {h}" for h in hints)
                      + ("" if hints else f"; known: {', '.join(sorted(known))}"))


def check_field(cls: type, name: str, raw: Any, label: str) -> Any:
    """``raw`` checked as field ``name`` of the params dataclass ``cls`` (its type and :data:`RULES`), for a
    value that came from elsewhere (a command-line flag): a ParamsError reads ``<label> is <raw>; set it to
    ...`` (``label`` e.g. ``--min-motion``), naming no params file."""
    f = next(f for f in dataclasses.fields(cls) if f.name == name)
    return _check("", label, raw, typing.get_type_hints(cls)[name], f.metadata)


def _at(path: str, key: str) -> str:
    return f"{path}: {key}" if path else key


def _file(params: dict[str, Any]) -> str:
    return str(params.get("_file", DEFAULT_PARAMS))


def _build(path: str, key: str, node: Any, classes: tuple[type, ...], given: dict[str, Any]) -> list[Any]:
    if not isinstance(node, dict):
        raise ParamsError(f"{path}: {key}: expected a section of keys, got {short(node)}")
    fields = {f.name: (cls, f) for cls in reversed(classes) for f in dataclasses.fields(cls)
              if f.init and not f.metadata.get("fixed")}
    if set(given) - set(fields):
        raise TypeError(f"{key}: given values {sorted(set(given) - set(fields))} are no fields of {classes}")
    reject_unknown(path, key, node, [name for name in fields if name not in given])
    kwargs: dict[type, dict[str, Any]] = {cls: {} for cls in classes}
    hints = {cls: typing.get_type_hints(cls) for cls in classes}
    for name, (cls, f) in fields.items():
        if name in given:
            kwargs[cls][name] = given[name]
        elif name not in node:
            raise ParamsError(f"{path}: missing parameter '{key}.{name}'; add it to {path}")
        else:
            kwargs[cls][name] = _check(path, f"{key}.{name}", node[name], hints[cls][name], f.metadata)
    out = []
    for cls in classes:
        try:
            out.append(cls(**kwargs[cls]))
        except (TypeError, ValueError) as exc:  # "field ..." is reported as key.field, "key.field ..." as is
            first = str(exc).split(" ")[0]
            prefix = "" if first.startswith(f"{key}.") else f"{key}." if first in fields else f"{key}: "
            raise ParamsError(f"{path}: {prefix}{exc}") from None
    return out


def _check(path: str, key: str, raw: Any, kind: Any, rules: Any = None) -> Any:
    """``raw`` as type ``kind`` (int, float, str, bool, Device, Literal, Optional, tuple, list, dict, Any,
    a dataclass) and within ``rules``; else a ParamsError naming ``path: key``."""
    v = _coerce(path, key, raw, kind)
    for rule, limit in (rules or {}).items():
        test, text = RULES[rule]
        if v is not None and not test(v, limit):
            raise ParamsError(f"{_at(path, key)} is {short(v)}; set it to {text.format(limit)}")
    return v


def _coerce(path: str, key: str, raw: Any, kind: Any) -> Any:
    origin, args = typing.get_origin(kind), typing.get_args(kind)

    def bad(expected: str) -> ParamsError:
        return ParamsError(f"{_at(path, key)} is {short(raw)}; set it to {expected}")

    if kind is Any:
        return raw
    if origin in (typing.Union, types.UnionType):
        if raw is None and type(None) in args:
            return None
        rest = [a for a in args if a is not type(None)]
        if len(rest) == 1:
            return _coerce(path, key, raw, rest[0])
        raise TypeError(f"{key}: unsupported annotation {kind}")
    if origin is typing.Literal:
        if raw not in args or isinstance(raw, bool) != isinstance(args[0], bool):
            raise bad("one of " + ", ".join(str(a) for a in args))
        return raw
    if origin in (tuple, list):
        if not isinstance(raw, (list, tuple)):
            raise bad("a list [...]")
        if origin is tuple and not (len(args) == 2 and args[1] is Ellipsis):
            if len(raw) != len(args):
                raise bad(f"a list of {len(args)} values")
            items = [_coerce(path, f"{key}[{i}]", x, a) for i, (x, a) in enumerate(zip(raw, args))]
        else:
            items = [_coerce(path, f"{key}[{i}]", x, args[0] if args else Any) for i, x in enumerate(raw)]
        return origin(items)
    if kind is dict or origin is dict:
        if not isinstance(raw, dict):
            raise bad("a mapping {key: value}")
        return dict(raw)
    if dataclasses.is_dataclass(kind):
        return _build(path, key, raw, (kind,), {})[0]
    if kind is bool:
        if not isinstance(raw, bool):
            raise bad("true or false" + (" (YAML booleans, without quotes)" if isinstance(raw, str) else ""))
        return raw
    if kind is int:
        if isinstance(raw, bool) or not isinstance(raw, (int, float)) or (
                isinstance(raw, float) and not raw.is_integer()):
            raise bad("an integer")
        return int(raw)
    if kind is float:
        if isinstance(raw, str):  # YAML 1.1 reads 1e-4 (no dot) as a string
            try:
                raw = float(raw)
            except ValueError:
                raise bad("a finite number") from None
        if isinstance(raw, bool) or not isinstance(raw, (int, float)) or not math.isfinite(raw):
            raise bad("a finite number")
        return float(raw)
    if kind is Device:
        if not isinstance(raw, str) or not _DEVICE.fullmatch(raw):
            raise bad(DEVICES)
        return str(raw)
    if kind is str:
        if not isinstance(raw, str):
            raise bad("a string")
        return raw
    raise TypeError(f"{key}: unsupported annotation {kind}")


#: The pretrained starts of the paper's model: params key → what file it must name.
PRETRAINED_STARTS = {
    "train_depth.imagenet_weights": "a torchvision resnet18 ImageNet state_dict (.pth), the start of both "
                                    "ResNet-18s (P²Net's weights_init: pretrained)",
    "flow_pretrain.checkpoint": "ARFlow's 2-frame Sintel model Sintel/pwclite_ar.tar (pwclite_ar_mv is a "
                                "3-frame model and does not load), the start of the flow network",
}


def pretrained_starts(params: dict[str, Any], keys: tuple[str, ...]) -> dict[str, str | None]:
    """The pretrained weight files ``keys`` (of :data:`PRETRAINED_STARTS`) name, None where random.

    With ``allow_random_init: false`` (the ``paper`` profile) every key must name an existing file: the
    paper starts both ResNets from ImageNet and PWC-Lite from ARFlow's Sintel model, so a run without them
    would not be the paper's model. Raises :class:`ParamsError` (one line: the key, the file expected and
    the opt-out) before any work is done. With ``allow_random_init: true`` (the CPU default) an unset key
    means a random start.
    """
    path = _file(params)
    allow = get(params, "allow_random_init")
    if not isinstance(allow, bool):
        raise ParamsError(f"{path}: allow_random_init must be true or false, got {short(allow)}")
    out: dict[str, str | None] = {}
    for key in keys:
        file = get(params, key, None)
        if file in (None, ""):
            if not allow:
                raise ParamsError(f"{path}: {key} is not set; the paper's model needs "
                                  f"{PRETRAINED_STARTS[key]}. Point {key} at that file, or set "
                                  "allow_random_init: true to train from random weights")
            out[key] = None
            continue
        if not Path(file).is_file():
            raise ParamsError(f"{path}: {key} = {clip(str(file))}: file not found; it must be "
                              f"{PRETRAINED_STARTS[key]}")
        out[key] = str(file)
    return out
