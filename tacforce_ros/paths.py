"""Where the package's data (config/, launch/) lives, installed or in the source tree; and the
check every tool makes of its output folder before long work."""
import argparse
import json
import os
import tempfile
from pathlib import Path

PACKAGE = 'tacforce_ros'


def share_dir() -> Path:
    """The folder holding config/ and launch/.

    TACFORCE_SHARE_DIR wins; then the source tree next to this package (a develop/editable
    install or a plain checkout); then the installed ament share folder.
    """
    override = os.environ.get('TACFORCE_SHARE_DIR')
    if override:
        return Path(override)
    source_root = Path(__file__).resolve().parent.parent
    if (source_root / 'config').is_dir():
        return source_root
    try:
        from ament_index_python.packages import get_package_share_directory
    except ImportError as exc:
        raise FileNotFoundError(
            f'{PACKAGE} data not found: no config/ next to the package and no ament index') from exc
    return Path(get_package_share_directory(PACKAGE))


def config_dir() -> Path:
    return share_dir() / 'config'


def ros_home() -> Path:
    """ROS's per-user folder: ROS_HOME, else ~/.ros (as rcl_logging and ros2 cli use)."""
    return Path(os.environ.get('ROS_HOME') or Path.home() / '.ros')


class OutputError(OSError):
    """An output folder that cannot be created or written."""


def writable_folder(path: str | Path) -> Path:
    """Create `path` if needed and prove it takes a file (created and removed again), so a tool
    fails at its start, not after an hour of work; OutputError names the folder and the cause."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise OutputError(f'{path}: cannot write there ({exc.strerror or exc})') from None
    return path


def output_folder(value: str) -> Path:
    """argparse type of an output folder (--out): created and proved writable while the command
    line is parsed, before any work; otherwise the usual argparse error, exit code 2."""
    try:
        return writable_folder(value)
    except OutputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def output_file(value: str) -> Path:
    """argparse type of an output file: its folder as in output_folder."""
    path = Path(value)
    output_folder(str(path.parent))
    return path


def write_results(folder: Path, stem: str, result: dict, table: str) -> None:
    """A benchmark's results as <stem>.json and its readable table as <stem>.md, which is also
    printed, with where both went."""
    (folder / f'{stem}.json').write_text(json.dumps(result, indent=2))
    (folder / f'{stem}.md').write_text(table)
    print(table)
    print(f"wrote {folder / f'{stem}.json'}, {stem}.md")
