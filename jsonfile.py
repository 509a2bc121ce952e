"""Reading a JSON file so that every problem names the file.

Configuration, inventory, calibration and recorded captures are all JSON files a user writes or copies; a bad one
must say which file and what was wrong, in the error type of the module that reads it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def read_json(path: str | Path, error: type[Exception], what: str) -> Any:
    """The parsed content of ``path``; ``error("<path>: ...")`` when it cannot be read or is not JSON.

    ``what`` names the file's role in the message ("the grasps file", "capture metadata", ...)."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except OSError as e:
        raise error(f"{path}: cannot read {what} ({e.strerror})") from None
    except json.JSONDecodeError as e:
        raise error(f"{path}: not valid JSON ({what}: {e})") from None
