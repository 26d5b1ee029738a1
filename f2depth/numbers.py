"""A metric as text: the one number format of the stages' log lines and the tables' cells."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def format_number(value: Any, digits: int = 3) -> str:
    """``digits`` decimals for a real number, all digits for an integer, "-" for a missing or NaN value."""
    if value is None:
        return "-"
    if isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        return str(int(value))
    value = float(value)
    return "-" if math.isnan(value) else f"{value:.{digits}f}"
