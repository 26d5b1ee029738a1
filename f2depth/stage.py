"""The one error contract of the DVC stage scripts: a bad parameter or bad input data ends a stage with
one line on stderr naming the file and the fix, and exit status 1 — never a traceback. So does a training
run that diverged (``FloatingPointError``: an epoch of nothing but non-finite steps, see f2depth.epochs).

    if __name__ == "__main__":
        run_stage("flow_pretrain", main, sys.argv)
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence

from f2depth.data.errors import DataError
from f2depth.params import ParamsError


def run_stage(name: str, main: Callable[[list[str]], object], argv: Sequence[str]) -> None:
    """Call ``main(argv)``; a :class:`ParamsError`, :class:`DataError` or ``FloatingPointError`` becomes
    ``"<name>: <message>"`` on stderr and exit status 1 (other exceptions are bugs: they keep their
    traceback)."""
    try:
        main(list(argv))
    except (ParamsError, DataError, FloatingPointError) as exc:
        sys.stderr.write(f"{name}: {exc}\n")
        raise SystemExit(1) from None
