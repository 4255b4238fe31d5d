"""A virtual environment with one package pip-installed into it, for the tests that prove
something works installed beside rigidbench rather than from this checkout."""

import subprocess
import sys
import venv
from pathlib import Path

# pip install of a small package without dependencies (the venv sees this environment's):
# building it fetches setuptools from the registry.
INSTALL_TIMEOUT_S = 300


def venv_with(package: Path, where: Path) -> Path:
    """The Python of a venv at `where` that sees this environment's packages and has `package`
    (a source directory) installed."""
    venv.EnvBuilder(system_site_packages=True, with_pip=False).create(where)
    python = where / "bin" / "python"
    install = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps"]
        + ["--quiet", "--disable-pip-version-check", str(package)],
        capture_output=True,
        text=True,
        timeout=INSTALL_TIMEOUT_S,
    )
    assert install.returncode == 0, install.stderr
    return python
