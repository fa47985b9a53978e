"""Where the package's data (config/, launch/) lives, installed or in the source tree."""
import os
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
