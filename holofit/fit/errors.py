"""The fit stage's own error."""

from __future__ import annotations

__all__ = ["FitStageError"]


class FitStageError(RuntimeError):
    """A fit stage cannot go on (e.g. the initial pass left no frame to average)."""
