"""Writes .dvc/plots/offline.html, the page `dvc plots show` fills (DVC config `plots.html_template`), with
vega, vega-lite and vega-embed inlined: DVC's own page loads them from a CDN and stays blank offline.

Usage (the minified builds of the npm packages; .dvc/plots/README.md names the versions in use):
    npm pack vega@5 vega-lite@5 vega-embed@6
    python tools/plots_html.py vega-5.*.tgz vega-lite-5.*.tgz vega-embed-6.*.tgz

The scripts are inlined, not linked: DVC writes the page into `dvc_plots/` of the directory it runs in (or
`-o DIR`), so no relative path to a file of the repository holds for every run.
"""

from __future__ import annotations

import json
import sys
import tarfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / ".dvc" / "plots" / "offline.html"
PACKAGES = ("vega", "vega-lite", "vega-embed")  # in this order: vega-embed needs the other two loaded
PLACEHOLDERS = ("{plot_divs}", "{scripts}", "{refresh_tag}")  # what dvc_render.html.HTML replaces

PAGE = """<!DOCTYPE html>
<html>
<head>
    {refresh_tag}
    <meta charset="utf-8">
    <title>DVC plots (f2depth)</title>
    <!-- Written by tools/plots_html.py; licences and versions: .dvc/plots/README.md. No placeholder
         for DVC's scripts (links to a CDN): the three libraries are below. -->
__SCRIPTS__
    <style>
        body { font-family: sans-serif; }
        table { border-spacing: 15px; }
    </style>
</head>
<body>
    {plot_divs}
</body>
</html>
"""


def package_script(tgz: Path) -> tuple[str, str, str, str]:
    """``(name, version, licence, minified build)`` of an ``npm pack`` tarball."""
    with tarfile.open(tgz) as tar:
        meta = json.load(tar.extractfile("package/package.json"))
        name = meta["name"]
        code = tar.extractfile(f"package/build/{name}.min.js").read().decode("utf-8")
    return name, meta["version"], meta.get("license", "?"), code


def page(tarballs: list[Path]) -> str:
    found = {name: (version, licence, code) for name, version, licence, code in map(package_script, tarballs)}
    missing = [name for name in PACKAGES if name not in found]
    if missing:
        raise SystemExit(f"plots_html: no tarball of {', '.join(missing)}; run `npm pack` for it first")
    blocks = []
    for name in PACKAGES:
        version, licence, code = found[name]
        bad = [s for s in ("</script", *PLACEHOLDERS) if s in code.lower()]
        if bad:
            raise SystemExit(f"plots_html: {name} {version} contains {bad[0]!r}: it cannot be inlined as is")
        blocks.append(f"    <!-- {name} {version} ({licence}), build/{name}.min.js -->\n"
                      f"    <script>{code.strip()}</script>")
    return PAGE.replace("__SCRIPTS__", "\n".join(blocks))


def main(argv: list[str]) -> None:
    if len(argv) < 2:
        raise SystemExit(__doc__)
    OUT.write_text(page([Path(a) for a in argv[1:]]), encoding="utf-8")
    print(f"plots_html: {OUT.relative_to(ROOT)} ({OUT.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main(sys.argv)
