"""Stage outputs cached on disk under a key that hashes everything they depend on.

A key is the sha256 of a JSON spec: the stage's parameters, the digests of the files it reads
(scenes, parameter files, command sequences, hand description) and of the source code that
computes it, and the keys of the upstream outputs it uses. Change any of them and only what
depends on it gets a new key and is recomputed. Entries are written to a temporary name and
renamed, so an interrupted run never leaves a half-written entry behind.
"""
from __future__ import annotations

import ast
import dataclasses
import functools
import hashlib
import json
import os
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Callable

PACKAGE_ROOT = Path(__file__).resolve().parents[1]
PACKAGE = PACKAGE_ROOT.name


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


def _module_file(module: str) -> Path | None:
    """The source file of a dotted module name of this package, or None."""
    base = PACKAGE_ROOT.joinpath(*module.split('.')[1:])
    for path in (base.with_suffix('.py'), base / '__init__.py'):
        if path.is_file():
            return path
    return None


def _imported_modules(path: Path) -> set[str]:
    """This package's modules that a source file imports anywhere (function bodies included)."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.split('.')[0] == PACKAGE}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module \
                and node.module.split('.')[0] == PACKAGE:
            found.add(node.module)
            found |= {f'{node.module}.{a.name}' for a in node.names
                      if _module_file(f'{node.module}.{a.name}') is not None}
    return found


@functools.lru_cache(maxsize=None)
def source_files(*modules: str) -> tuple[Path, ...]:
    """The files of `modules` and of everything of this package they import, transitively, with
    the packages on the way (their __init__ runs on import). Kept per process: the sources do
    not change while a run computes its keys (the digest still reads their bytes each time)."""
    seen: dict[str, Path] = {}
    todo = list(modules)
    while todo:
        module = todo.pop()
        parts = module.split('.')
        for name in ('.'.join(parts[:k]) for k in range(1, len(parts) + 1)):
            if name in seen:
                continue
            path = _module_file(name)
            if path is None:
                if name == module:
                    raise ValueError(f'{module}: no such module in {PACKAGE}')
                continue
            seen[name] = path
            todo += sorted(_imported_modules(path))
    return tuple(sorted(set(seen.values())))


def source_digest(*targets: str | Callable | type) -> str:
    """sha256 of the source code behind `targets` (functions, classes, or dotted module names for
    what runs in a subprocess): their modules and everything those import, so a cache key follows
    the code that computes its entry without a list of folders to keep up to date."""
    modules = [t if isinstance(t, str) else t.__module__ for t in targets]
    h = hashlib.sha256()
    for path in source_files(*modules):
        h.update(str(path.relative_to(PACKAGE_ROOT)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def node_modules() -> list[str]:
    """Modules of this package's node executables: what a session started by name may run."""
    return sorted(ep.module for ep in entry_points(group='console_scripts')
                  if ep.module.startswith(f'{PACKAGE}.nodes.'))


def tool_modules(*executables: str) -> list[str]:
    """Modules behind this package's executables of these names (as installed), for the digest
    of what a stage runs as a command."""
    found = {ep.name: ep.module for ep in entry_points(group='console_scripts')
             if ep.module.startswith(f'{PACKAGE}.')}
    missing = [name for name in executables if name not in found]
    if missing:
        raise ValueError(f'{missing}: not executables of {PACKAGE} (run ./run.sh setup)')
    return sorted(found[name] for name in executables)


def atomic_write(path: str | Path, write: Callable[[Path], object]) -> Path:
    """write(tmp) fills a temporary file beside `path` (same suffix, so writers that append one
    do not), which is then renamed into place: readers never see a half-written file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f'.{path.stem}.{os.getpid()}.tmp{path.suffix}')
    write(tmp)
    os.replace(tmp, path)
    return path


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
        return atomic_write(path, lambda tmp: tmp.write_text(json.dumps(value, indent=1)))

    def store_file(self, stage: str, key: str, suffix: str, write) -> Path:
        """write(tmp_path) produces the entry; it is renamed into place afterwards."""
        return atomic_write(self.path(stage, key, suffix), write)
