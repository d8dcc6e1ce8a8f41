"""``BuildResult``: what ``Matcher.build`` returns (ONNX export and TensorRT builds alike)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["BuildResult", "PARITY_TOLERANCE"]

PARITY_TOLERANCE = 1e-4


@dataclass
class BuildResult:
    """Outcome of ``Matcher.build``. ``parity``: "<graph>/<output>[<case>]" and
    "similarity[<case>]" -> max |torch - onnx|; ``parity_ok`` is True only when parity was
    checked and every value is <= ``tolerance``. ``logs``: trtexec logs (TensorRT builds)."""

    target: str
    model: str
    output_dir: Path
    artifacts: list[Path] = field(default_factory=list)
    parity: dict[str, float] = field(default_factory=dict)
    logs: list[Path] = field(default_factory=list)
    site: str = ""
    parity_checked: bool = False
    tolerance: float = PARITY_TOLERANCE
    notes: list[str] = field(default_factory=list)
    precision: str | None = None

    @property
    def parity_ok(self) -> bool:
        return bool(self.parity_checked and self.parity and all(v <= self.tolerance for v in self.parity.values()))

    @property
    def max_parity_error(self) -> float:
        return max(self.parity.values()) if self.parity else float("nan")

    def to_dict(self) -> dict[str, Any]:
        return {"target": self.target, "model": self.model, "site": self.site, "output_dir": str(self.output_dir),
                "artifacts": [str(a) for a in self.artifacts], "parity": self.parity,
                "parity_checked": self.parity_checked, "parity_ok": self.parity_ok, "tolerance": self.tolerance,
                "max_parity_error": self.max_parity_error if self.parity else None,
                "logs": [str(p) for p in self.logs], "notes": self.notes, "precision": self.precision}
