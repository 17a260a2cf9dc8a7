"""Errors of the crop stage."""

from __future__ import annotations

__all__ = ["CropError", "FrameError"]


class CropError(ValueError):
    """Input the crop stage cannot use; the message names the file (and frame, if any)."""


class FrameError(ValueError):
    """One frame cannot be processed; the batch records it with status ``error`` and goes on."""
