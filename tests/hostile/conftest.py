import pytest

from . import corpus


@pytest.fixture(scope="session")
def logs():
    d = corpus.logs_dir()
    if not (d / "vtol.tlog").exists():
        pytest.skip("shared logs not found at repo_root/../shared/logs")
    return d
