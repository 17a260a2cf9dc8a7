"""mkdocs hooks of holofit's documentation site.

The calibration study's plot lives with its data in ``bench/results/calibration/``; the
validation page shows it without a second copy in ``docs/``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

#: files outside docs/ that pages show: the URI in the site -> the path in the repository
EXTRA_FILES = {
    "validation/calibration.png": "bench/results/calibration/calibration.png",
}


def on_files(files: Files, config: Any) -> Files:
    root = Path(config["config_file_path"]).parent
    for uri, path in EXTRA_FILES.items():
        files.append(File.generated(config, uri, abs_src_path=str(root / path)))
    return files
