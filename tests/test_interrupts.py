"""Killed and terminated runs leave nothing behind (issue 25, item 8): the temporaries of a run killed with
-9 are cleared by the next run, and SIGTERM ends a stage or the CLI as Ctrl-C does (atomic writers clean
up, one line, exit 143). Before: kill -9 during `prepare` left `.<out>.tmp-PID` folders for good and
SIGTERM to `train_depth` left `models/.depth_<variant>.tmp-PID`."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from f2depth.io import OUTPUT_MARKER, atomic_dir, clear_stale_temporaries

ROOT = Path(__file__).resolve().parents[1]


def dead_pid() -> int:
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    return int(proc.stdout)


def run_and_kill(script: str, sig: int, ready: Path, timeout: float = 60.0) -> subprocess.CompletedProcess:
    """Run ``script`` in a fresh interpreter, wait until it creates ``ready``, send ``sig``."""
    proc = subprocess.Popen([sys.executable, "-c", textwrap.dedent(script)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT)
    deadline = time.monotonic() + timeout
    while not ready.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the child never got ready"
        time.sleep(0.05)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=timeout)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


HOLD_AN_ATOMIC_DIR = """
    import sys, time
    from pathlib import Path
    from f2depth.io import atomic_dir
    from f2depth.stage import run_stage

    def main(argv):
        with atomic_dir(Path(argv[1]) / "out", "hold", owned=True) as tmp:
            (tmp / "half.txt").write_text("half of the output")
            Path(argv[1], "ready").touch()
            time.sleep(60)

    run_stage("hold", main, ["hold", {root!r}])
"""


def test_kill_9_leaves_a_temporary_that_the_next_run_clears(tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "good.txt").write_text("the previous good output")
    run = run_and_kill(HOLD_AN_ATOMIC_DIR.format(root=str(tmp_path)), signal.SIGKILL, tmp_path / "ready")
    assert run.returncode == -signal.SIGKILL
    stale = [p.name for p in tmp_path.iterdir() if p.name.startswith(".out.tmp-")]
    assert len(stale) == 1  # what kill -9 leaves: nothing can clean up inside the killed process
    with atomic_dir(tmp_path / "out", "hold", owned=True) as tmp:
        (tmp / "new.txt").write_text("new")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "ready"]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [OUTPUT_MARKER, "new.txt"]


def test_sigterm_ends_a_stage_like_ctrl_c(tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "good.txt").write_text("the previous good output")
    run = run_and_kill(HOLD_AN_ATOMIC_DIR.format(root=str(tmp_path)), signal.SIGTERM, tmp_path / "ready")
    assert run.returncode == 143
    assert run.stderr.splitlines() == [
        "hold: terminated (SIGTERM); no output was half-written, and a stage that keeps a resume state "
        "continues from its last completed epoch when run again"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "ready"]  # no .out.tmp-PID left
    assert (tmp_path / "out" / "good.txt").read_text() == "the previous good output"


def test_stale_temporaries_of_dead_processes_only(tmp_path):
    dead, alive = dead_pid(), os.getppid()
    for name in (f".out.tmp-{dead}", f".out.tmp-{alive}", f".other.tmp-{dead}", f".out.old-{dead}"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "f").write_text(name)
    removed = clear_stale_temporaries(tmp_path / "out")
    # the dead run had moved the good output aside and died before renaming the new one in: restored
    assert sorted(p.name for p in removed) == [f".out.old-{dead}", f".out.tmp-{dead}"]
    assert (tmp_path / "out" / "f").read_text() == f".out.old-{dead}"
    assert sorted(p.name for p in tmp_path.iterdir()) == [f".other.tmp-{dead}", f".out.tmp-{alive}", "out"]
    (tmp_path / f".out.old-{dead}").mkdir()  # with the output in place, an old copy is just deleted
    assert clear_stale_temporaries(tmp_path / "out") == [tmp_path / f".out.old-{dead}"]
    assert (tmp_path / "out" / "f").read_text() == f".out.old-{dead}"


def test_sigterm_ends_the_cli_like_ctrl_c(tmp_path):
    script = f"""
        import sys, time
        from pathlib import Path
        import f2depth.cli as cli

        def slow(args):
            Path({str(tmp_path / 'ready')!r}).touch()
            time.sleep(60)

        cli._cmd_predict = slow  # the parser binds the command when main builds it
        sys.exit(cli.main(["predict", "--model", "m.pt", "--input", "in", "--output", "out"]))
    """
    run = run_and_kill(script, signal.SIGTERM, tmp_path / "ready")
    assert run.returncode == 143
    assert run.stderr.splitlines() == ["f2depth predict: error: terminated (SIGTERM); every file written so "
                                       "far is complete"]
