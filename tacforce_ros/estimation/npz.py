"""Reading .npz files (model files, datasets) without pickle, with a cause a person can act on."""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np


def read_npz(path: str | Path) -> dict[str, np.ndarray]:
    """Every entry of a .npz file. FileNotFoundError if absent; ValueError naming the cause
    otherwise (numpy alone calls a text file "pickled data": it is simply not a zip archive)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(path)
    if not zipfile.is_zipfile(path):
        raise ValueError('not a .npz file: a .npz is a zip archive and this file is not one')
    try:
        with np.load(path, allow_pickle=False) as npz:
            return {key: npz[key] for key in npz.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
        raise ValueError(f'damaged .npz file: {exc}') from None
