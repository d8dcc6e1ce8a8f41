"""A restricted pickle loader for dataset info files (mmdetection3d ``.pkl``): only builtin
containers, numpy arrays/scalars/dtypes and ``_codecs.encode`` may be rebuilt; any other class
in the pickle is refused, so loading never runs code from the file."""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FormatError

__all__ = ["load_pickle_restricted"]

_ALLOWED = {
    ("numpy", "dtype"), ("numpy", "ndarray"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.numeric", "_frombuffer"), ("numpy._core.numeric", "_frombuffer"),
    ("_codecs", "encode"),
    ("builtins", "set"), ("builtins", "frozenset"), ("builtins", "slice"), ("builtins", "complex"),
    ("collections", "OrderedDict"),
}


class _Restricted(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        if (module, name) not in _ALLOWED:
            raise pickle.UnpicklingError(f"refusing to load {module}.{name} (only numpy data and builtins)")
        if module.startswith("numpy._core") and not hasattr(np, "_core"):
            module = module.replace("numpy._core", "numpy.core")
        return super().find_class(module, name)


#: Largest info pickle read (read whole, then unpickled from memory).
MAX_PICKLE_BYTES = 1 << 30


def load_pickle_restricted(path, max_bytes: int = MAX_PICKLE_BYTES) -> Any:
    """Load a pickle made of dicts/lists/numpy data; FormatError for anything else.

    The file passes the special-file and size checks of every reader and is unpickled from
    memory: a corrupted length field cannot make the unpickler allocate more than the file
    holds (reading from a file object, ``read(n)`` reserves the ``n`` bytes a length claims)."""
    import io

    from ..io.files import read_bytes

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"pickle not found: {path}")
    data = read_bytes(path, max_bytes=max_bytes, what="pickle")
    try:
        return _Restricted(io.BytesIO(data), encoding="latin1").load()
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, ValueError, TypeError, KeyError,
            IndexError, OverflowError, RecursionError, MemoryError, UnicodeDecodeError) as exc:
        raise FormatError(path, f"not a plain-data pickle ({type(exc).__name__}: {str(exc)[:160]})") from None
