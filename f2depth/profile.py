"""Switch params.yaml between the small CPU default and the paper's scale.

    python -m f2depth.profile paper      # or: make paper
    python -m f2depth.profile cpu        # or: make cpu
    python -m f2depth.profile --show     # list the profiles and what they set

Profiles live in ``configs/profiles.yaml`` as dotted keys; only those keys change, comments stay.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path
from typing import Any

from ruamel.yaml import YAML

from f2depth import io as fio
from f2depth import params as P

PROFILES = Path("configs/profiles.yaml")


def _yaml() -> YAML:
    y = YAML()
    y.preserve_quotes = True
    y.width = 120
    # a null stays `null` (ruamel's round trip would write an empty value: the same YAML, a noisy diff)
    y.representer.add_representer(type(None),
                                  lambda r, _: r.represent_scalar("tag:yaml.org,2002:null", "null"))
    return y


def _checked(path: Path) -> None:
    """Read ``path`` as the stages read YAML first (f2depth.params.load: a key given twice or aliases that
    expand to a bomb end the command with that one line)."""
    try:
        P.load(path)
    except P.ParamsError as exc:
        raise SystemExit(str(exc)) from None


def load_profiles(path: Path = PROFILES) -> dict[str, dict[str, Any]]:
    _checked(path)
    with path.open() as fh:
        return dict(_yaml().load(fh))


def apply(name: str, params_path: Path = Path("params.yaml"), profiles_path: Path = PROFILES) -> list[str]:
    """Write profile ``name`` into ``params_path``; returns the keys whose value changed."""
    profiles = load_profiles(profiles_path)
    if name not in profiles:
        raise SystemExit(f"{profiles_path}: no profile '{name}' (have: {', '.join(profiles)})")
    _checked(params_path)
    y = _yaml()
    with params_path.open() as fh:
        doc = y.load(fh)
    changed = []
    for dotted, value in profiles[name].items():
        node = doc
        *parents, leaf = dotted.split(".")
        for part in parents:
            if part not in node:
                raise SystemExit(f"{params_path}: profile key '{dotted}' has no section '{part}'")
            node = node[part]
        if leaf not in node:
            raise SystemExit(f"{params_path}: profile key '{dotted}' does not exist")
        if node[leaf] != value:
            node[leaf] = value
            changed.append(dotted)
    buf = io.StringIO()
    y.dump(doc, buf)
    fio.write_text(params_path, buf.getvalue())
    return changed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m f2depth.profile", description=__doc__.splitlines()[0])
    ap.add_argument("name", nargs="?", help="profile to apply (cpu | paper)")
    ap.add_argument("--params", type=Path, default=Path("params.yaml"))
    ap.add_argument("--profiles", type=Path, default=PROFILES)
    ap.add_argument("--show", action="store_true", help="print the profiles and exit")
    args = ap.parse_args(argv)
    if args.show or not args.name:
        for name, values in load_profiles(args.profiles).items():
            sys.stdout.write(f"{name}:\n" + "".join(f"  {k}: {v}\n" for k, v in values.items()))
        return 0
    changed = apply(args.name, args.params, args.profiles)
    sys.stdout.write(f"{args.params}: profile '{args.name}' applied; changed {len(changed)} keys")
    sys.stdout.write((": " + ", ".join(changed) if changed else "") + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
