"""The one error contract of the DVC stage scripts: a bad parameter or bad input data ends a stage with
one line on stderr naming the file and the fix, and exit status 1 — never a traceback. So does a training
run that diverged (``FloatingPointError``: an epoch of nothing but non-finite steps, see f2depth.epochs)
and a full disk (``OSError`` ENOSPC, which f2depth.io raises naming the file). Ctrl-C and SIGTERM
(f2depth.signals) end it with one line and exit 130 / 143, after the atomic writers have cleaned up.

    if __name__ == "__main__":
        run_stage("flow_pretrain", main, sys.argv)
"""

from __future__ import annotations

import errno
import os
import sys
from collections.abc import Callable, Sequence

from f2depth.errors import DataError
from f2depth.params import MAX_LINE, ParamsError, clip
from f2depth.signals import Terminated, sigterm_as_interrupt


def _say(name: str, text: str) -> None:
    """One line on stderr, from rank 0 only: under ``torchrun`` every rank fails alike."""
    if os.environ.get("RANK", "0") == "0":
        sys.stderr.write(f"{name}: {clip(text, MAX_LINE)}\n")


def run_stage(name: str, main: Callable[[list[str]], object], argv: Sequence[str]) -> None:
    """Call ``main(argv)``; a :class:`ParamsError`, :class:`DataError` or ``FloatingPointError`` becomes
    ``"<name>: <message>"`` on stderr and exit status 1 (other exceptions are bugs: they keep their
    traceback). Under ``torchrun`` only rank 0 writes the line; every rank exits 1."""
    try:
        with sigterm_as_interrupt():
            main(list(argv))
    except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM: the atomic writers have cleaned up on the way out
        how = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"
        _say(name, f"{how}; no output was half-written, and a stage that keeps a resume state continues from "
                   "its last completed epoch when run again")
        raise SystemExit(143 if isinstance(exc, Terminated) else 130) from None
    except (ParamsError, DataError, FloatingPointError) as exc:
        _say(name, str(exc))
        raise SystemExit(1) from None
    except OSError as exc:
        if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
            raise
        _say(name, f"{exc.filename}: {exc.strerror}" if exc.filename else str(exc.strerror))  # f2depth.io
        raise SystemExit(1) from None
