"""Stage outputs cached on disk under a key that hashes everything they depend on.

A key is the sha256 of a JSON spec: the stage's parameters, the digests of the files it reads
(scenes, parameter files, command sequences, hand description) and of the source code that
computes it, and the keys of the upstream outputs it uses. Change any of them and only what
depends on it gets a new key and is recomputed. Entries are written to a temporary name and
renamed, so an interrupted run never leaves a half-written entry behind.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path
from typing import Any

PACKAGE_ROOT = Path(__file__).resolve().parents[1]


def digest(value: Any) -> str:
    """sha256 of a JSON-serialisable value (keys sorted)."""
    text = json.dumps(value, sort_keys=True, default=str, separators=(',', ':'))
    return hashlib.sha256(text.encode()).hexdigest()


def file_digest(*paths: str | Path) -> str:
    """sha256 over the bytes of files (in the given order)."""
    h = hashlib.sha256()
    for path in paths:
        h.update(Path(path).read_bytes())
    return h.hexdigest()


def code_digest(*parts: str) -> str:
    """sha256 of the package sources under `parts` (subpackages or module files)."""
    files: list[Path] = []
    for part in parts:
        path = PACKAGE_ROOT / part
        files += sorted(path.rglob('*.py')) if path.is_dir() else [path.with_suffix('.py')]
    h = hashlib.sha256()
    for path in files:
        h.update(str(path.relative_to(PACKAGE_ROOT)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def scene_digest(scene_name: str | Path) -> str:
    """Digest of a scene as loaded (its whole extends chain merged), without its file path."""
    from tacforce_ros.sim import load_scene
    scene = dataclasses.asdict(load_scene(scene_name))
    scene.pop('path')
    return digest(scene)


class StageCache:
    """Files under <root>/<stage>/<key>.<suffix>."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.hits = 0
        self.misses = 0

    def path(self, stage: str, key: str, suffix: str) -> Path:
        return self.root / stage / f'{key[:24]}{suffix}'

    def lookup(self, stage: str, key: str, suffix: str) -> Path | None:
        path = self.path(stage, key, suffix)
        if path.exists():
            self.hits += 1
            return path
        self.misses += 1
        return None

    def load_json(self, stage: str, key: str) -> Any | None:
        path = self.lookup(stage, key, '.json')
        return None if path is None else json.loads(path.read_text())

    def store_json(self, stage: str, key: str, value: Any) -> Path:
        path = self.path(stage, key, '.json')
        return self._commit(path, lambda tmp: tmp.write_text(json.dumps(value, indent=1)))

    def _commit(self, path: Path, write) -> Path:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f'.{path.name}.{os.getpid()}.tmp')
        write(tmp)
        os.replace(tmp, path)
        return path

    def store_file(self, stage: str, key: str, suffix: str, write) -> Path:
        """write(tmp_path) produces the entry; it is renamed into place afterwards."""
        return self._commit(self.path(stage, key, suffix), write)
