"""Stage settings of a run folder checked against the movie and the particle, before anything
is written: what the stages themselves would refuse only when make reaches them.

``holofit init``'s command line checks that every extra option exists and that its value
has the right type (the stage commands' own parsers); here the rules that need the inputs:
the crop side against the frame size (the default 140 too), the follow mode and start point,
the parameters ``--fix`` may name, and what the fit's initial pass will take.
"""

from __future__ import annotations

import shlex

from holofit.crop.errors import CropError
from holofit.crop.settings import DEFAULT_CROP_SIZE, TRACKS, check_crop_settings
from holofit.fit.defaults import INITIAL_MAX, INITIAL_MIN, INITIAL_SHARE, default_initial_frames
from holofit.particles import ParticleModel
from holofit.runfolder.errors import RunFolderError

__all__ = ["check_crop_options", "check_fit_options", "initial_pass_note", "option_value"]


def option_value(text: str, *names: str) -> str | None:
    """The value of the last of ``names`` in an option line (``--size 96``, ``--size=96``,
    ``-j 2``); None if absent, '' if it is the last word."""
    words = shlex.split(text)
    value = None
    for i, word in enumerate(words):
        for name in names:
            if word == name:
                value = words[i + 1] if i + 1 < len(words) else ""
            elif name.startswith("--") and word.startswith(name + "="):
                value = word[len(name) + 1:]
    return value


def _flag(text: str, name: str) -> bool:
    return name in shlex.split(text)


def check_crop_options(text: str, frame_shape: tuple[int, int]) -> None:
    """The crop's size, follow mode and start point against the movie's frames.

    Raises
    ------
    RunFolderError
        Naming ``--crop-opts`` and the option at fault (the default crop size included:
        a movie smaller than 140 x 140 pixels needs ``--crop-opts '--size N'``).
    """
    size_text = option_value(text, "--size")
    follow = option_value(text, "--follow") or TRACKS
    start_text = option_value(text, "--start")
    where = f"--crop-opts {text!r}" if text else "crop (no --crop-opts)"
    try:
        size = int(size_text) if size_text is not None else DEFAULT_CROP_SIZE
    except ValueError:
        raise RunFolderError(f"{where}: --size {size_text!r} is not a whole number of "
                             "pixels") from None
    start = None
    if start_text is not None:
        try:
            x, y = (float(v) for v in start_text.split(","))
        except ValueError:
            raise RunFolderError(f"{where}: --start {start_text!r}: expected X,Y in pixels "
                                 "(x = column, y = row)") from None
        start = (x, y)
    if size_text is None and size > min(frame_shape):
        raise RunFolderError(
            f"the movie's frames ({frame_shape[0]} x {frame_shape[1]} pixels) are smaller than "
            f"the default crop ({size} x {size}): give --crop-opts '--size N' with N <= "
            f"{min(frame_shape)}")
    try:
        check_crop_settings(frame_shape, size, follow, start)
    except CropError as exc:
        raise RunFolderError(f"{where}: {exc}") from None


def check_fit_options(text: str, model: ParticleModel) -> None:
    """``--fix`` names parameters the particle has.

    Raises
    ------
    RunFolderError
        Naming ``--fit-opts`` and the parameters the particle has.
    """
    from holofit.fit.task import check_fixed

    fixed = option_value(text, "--fix")
    if fixed is None:
        return
    names = tuple(n.strip() for n in fixed.split(",") if n.strip())
    try:
        check_fixed(model, names)
    except ValueError as exc:
        raise RunFolderError(f"--fit-opts {text!r}: {exc}") from None


def initial_pass_note(text: str, n_frames: int) -> str | None:
    """What the fit's initial pass will take when ``--initial-frames`` is not given."""
    if option_value(text, "--initial-frames") is not None or _flag(text, "--initial-frames"):
        return None
    k = default_initial_frames(n_frames)
    return (f"fit: the initial pass (every parameter free, by direct DDA solves) will take "
            f"{k} of the movie's {n_frames} frames that can be fitted (spread over the movie "
            "where the particle has a T-matrix, else the first ones; 1 in "
            f"{INITIAL_SHARE}, at least {INITIAL_MIN}, at most {INITIAL_MAX}); to choose: "
            "--fit-opts '--initial-frames N', or make FIT_OPTS='--initial-frames N'")
