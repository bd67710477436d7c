"""Where gtsweep finds its configuration and keeps generated files."""
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent.parent
PROJECT_DIR = PACKAGE_DIR.parent
CONF_DIR = PROJECT_DIR / "conf"
#: Generated data (rendered data sets, keypoint cache) lives here, relative to the working directory.
DEFAULT_CACHE_DIR = Path(".gtsweep_cache")
