"""Deployment: ONNX export with parity checks (``build``), a torch-free ONNX Runtime matcher
(``OnnxMatcher``), TensorRT engine builds through ``trtexec`` and the shape envelope.

Importing this package does not import torch; :mod:`xcalib.deploy.build` and
:mod:`xcalib.deploy.onnx_export` do (they export from a torch model).
"""

from __future__ import annotations

import importlib

_LAZY = {
    "BuildResult": "xcalib.deploy.build",
    "build": "xcalib.deploy.build",
    "BuildOptions": "xcalib.deploy.build",
    "OnnxMatcher": "xcalib.deploy.ort_runtime",
    "load_onnx": "xcalib.deploy.ort_runtime",
    "Envelope": "xcalib.deploy.chunking",
    "PROTOCOL_ENVELOPE": "xcalib.deploy.chunking",
    "find_trtexec": "xcalib.deploy.trt",
}

__all__ = list(_LAZY)


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'xcalib.deploy' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
