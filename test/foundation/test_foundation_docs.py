"""The repository stands alone and its README stays a user's document: no tracked file points to
documents or scripts the repository does not hold, or to the project's issue tracker (a
CHANGELOG may name what it likes), and the README is short enough to read top to bottom."""
import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
TEXT = ('.py', '.md', '.yaml', '.yml', '.urdf', '.xml', '.txt', '.cfg', '.toml', '.sh', '.msg',
        '.action', '.srv', '.ini')
# Written with character classes so that this file does not match itself.
POINTING_AWAY = re.compile(
    r'outside (the|this) (repositor[y]|repo|project)|not in (the|this) (repositor[y]|repo)'
    r'|ROS2_ON_THIS_MACHIN[E]|ARCHITECTUR[E]\.md|\.\.[/]shared|\bissue[s]? #?\d+'
    r'|\btask[s]? \d+\b', re.IGNORECASE)
OWN_DOCUMENT = re.compile(r'(?<![\w/.])((?:docs/)?[A-Z][A-Z0-9_]+\.md)')


def tracked_text_files() -> list[Path]:
    try:
        listed = subprocess.run(['git', 'ls-files'], cwd=REPO, capture_output=True, text=True,
                                check=True, timeout=60).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip('not a git checkout: the tracked files are not known')
    return [REPO / name for name in listed
            if name.endswith(TEXT) and not name.startswith('CHANGELOG')
            and (REPO / name).is_file()]


def test_nothing_points_outside_the_repository_or_to_an_issue():
    found = []
    for path in tracked_text_files():
        # Whitespace joined: a phrase broken over two lines is still found.
        flat = re.sub(r'\s+', ' ', path.read_text(errors='replace'))
        found += [f'{path.relative_to(REPO)}: ...{flat[max(0, m.start() - 40):m.end() + 20]}...'
                  for m in POINTING_AWAY.finditer(flat)]
    assert not found, '\n'.join(found)


def test_every_document_named_in_capitals_is_in_the_repository():
    """`PROTOCOLS.md`, `docs/SKIN_PHYSICS.md`, ...: each exists at the root or in docs/."""
    missing = []
    for path in tracked_text_files():
        for name in set(OWN_DOCUMENT.findall(path.read_text(errors='replace'))):
            if not ((REPO / name).is_file() or (REPO / 'docs' / name).is_file()):
                missing.append(f'{path.relative_to(REPO)}: {name}')
    assert not missing, missing


def test_the_readme_reads_top_to_bottom():
    lines = (REPO / 'README.md').read_text().splitlines()
    assert len(lines) <= 300, len(lines)
    long = [(number, len(line)) for number, line in enumerate(lines, 1) if len(line) > 160]
    assert not long, long
    assert (REPO / 'docs' / 'PROTOCOLS.md').is_file()
