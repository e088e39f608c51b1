"""The header line a calibration script writes on top of the config file it fits: the command that wrote it.

The calibration scripts import it as a sibling module (``from provenance import written_by``): each runs as
``python benchmarks/calibration/<script>.py`` from the repository root, its own folder on ``sys.path``.
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def written_by(script: str) -> str:
    """``# written by: python benchmarks/calibration/<script>.py <args>\\n`` for the running command.

    ``script`` is the calling script's ``__file__``; it is named by its path from the repository root and
    followed by the arguments it was given (``sys.argv[1:]``, shell-quoted), so rerunning the header's command
    writes the same header.
    """
    path = Path(script).resolve().relative_to(ROOT).as_posix()
    return f"# written by: {shlex.join(['python', path, *sys.argv[1:]])}\n"
