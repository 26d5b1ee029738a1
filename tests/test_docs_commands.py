"""The README's commands run as written: DVC's stage commands call `python`, so a block that runs stages
(`dvc repro`, `dvc exp run`) activates the venv first; `.venv/bin/dvc` alone would start the stages with
another Python, which stops at `import f2depth` (what the README's video route did on a fresh clone)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUNS_STAGES = re.compile(r"(^|[\s;&|])(\S*/)?dvc (repro|exp run)\b")


def bash_blocks(text: str) -> list[list[str]]:
    blocks, current = [], None
    for line in text.splitlines():
        if line.startswith("```"):
            if current is None and line.strip() in ("```bash", "```sh", "```shell"):
                current = []
            elif current is not None:
                blocks.append(current)
                current = None
        elif current is not None:
            current.append(line)
    return blocks


def unactivated_stage_runs(text: str) -> list[str]:
    """Bash-block lines that run DVC stages with no `source .venv/bin/activate` above them in the block."""
    bad = []
    for block in bash_blocks(text):
        active = False
        for line in block:
            command = line.split("#", 1)[0]
            active = active or ".venv/bin/activate" in command  # `source` or `.`
            if RUNS_STAGES.search(command) and not active:
                bad.append(line.strip())
    return bad


def test_the_check_finds_a_stage_run_without_the_venv():
    text = "```bash\n.venv/bin/dvc exp run -S a=1\n```\n```bash\nsource .venv/bin/activate\ndvc repro\n```\n"
    assert unactivated_stage_runs(text) == [".venv/bin/dvc exp run -S a=1"]
    assert unactivated_stage_runs("```bash\nmake repro   # runs `dvc repro`\ndvc exp show\n```\n") == []


def test_readme_and_docs_activate_the_venv_before_running_stages():
    files = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    bad = {f.relative_to(ROOT).as_posix(): lines
           for f in files if (lines := unactivated_stage_runs(f.read_text()))}
    assert not bad, f"activate the venv first (source .venv/bin/activate) in: {bad}"
