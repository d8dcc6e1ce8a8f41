"""Errors of the deployment path; each names the file or input it is about."""

from __future__ import annotations

from ..errors import FormatError, XcalibError

__all__ = ["DeployError", "ExportError", "RandomWeightsError", "OnnxFolderError", "StaleOnnxError",
           "EnvelopeError", "TrtexecNotFoundError", "TrtBuildError"]


class DeployError(XcalibError):
    """Base class of deployment errors."""


class ExportError(DeployError, RuntimeError):
    """A model could not be exported to ONNX."""


class RandomWeightsError(ExportError, ValueError):
    """Export of a model whose weights were never loaded (random initialisation)."""


class OnnxFolderError(DeployError, FormatError):
    """An ONNX folder is missing files, corrupted, or belongs to another model / site."""


class StaleOnnxError(OnnxFolderError):
    """The ONNX graphs in a folder were exported from other weights than the matcher's."""


class EnvelopeError(DeployError, ValueError):
    """A frame is outside the engine shape envelope and cannot be split for this model."""


class TrtexecNotFoundError(DeployError, FileNotFoundError):
    """No ``trtexec`` executable was found."""


class TrtBuildError(DeployError, RuntimeError):
    """``trtexec`` failed or wrote no engine."""
