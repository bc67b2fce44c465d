import pytest
from conftest import shared_log


@pytest.fixture(scope="session")
def logs():
    """The shared logs folder (corpus.logs_dir()), or skip with where it was looked for."""
    return shared_log("vtol.tlog").parent
