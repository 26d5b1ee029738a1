"""Optional dependencies (onnx, onnxruntime, open3d) are imported lazily, with a message that says how
to install them instead of a traceback."""

from __future__ import annotations

import importlib
from types import ModuleType

#: module → (pip extra of f2depth that provides it, extra hint for a failing import)
EXTRAS = {"onnx": ("onnx", ""), "onnxruntime": ("onnx", ""), "open3d": ("recon", "")}
_LIBUSB_HINT = "; open3d's wheel links libusb: on Debian/Ubuntu `apt-get install libusb-1.0-0`"


class MissingDependency(RuntimeError):
    """An optional package needed for the requested feature is not importable."""


def require(module: str, purpose: str) -> ModuleType:
    """Import ``module`` or raise :class:`MissingDependency` naming the feature and the install command."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        extra = EXTRAS.get(module, (module, ""))[0]
        hint = _LIBUSB_HINT if "libusb" in str(exc) else ""
        raise MissingDependency(f"{purpose} needs the optional package '{module}', which cannot be imported "
                                f"({exc}); install it with `pip install 'f2depth[{extra}]'`{hint}") from None
