"""Test-wide settings: BLAS pinned to one thread (as the command line does), because the
filters do many small matrix operations and a multithreaded BLAS on 2 shared cores only
adds synchronisation (the suite ran 2-7x slower without it)."""

import os
import signal

# A test run started in the background by a non-interactive shell (`cmd &`, nohup) inherits
# SIGINT ignored, and every child a test starts would inherit that too (an exec keeps an
# ignored signal, not a handler): the tests that stop a child with SIGINT need the default.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


#: The test files that take the most CPU (``python -m pytest -q --durations=60``: about a
#: minute or more each on 2 cores, together a third of the suite), sent to the workers first
#: (pyproject.toml's ``--dist loadfile --no-loadscope-reorder``): xdist's default order, the
#: files with the most tests first, left them to the end, where one worker ran them while
#: the other was idle (a 581-s suite for 1010 s of CPU). The order is only a schedule: every
#: file runs, in any order, alone or not.
HEAVY_FIRST = (
    "tests/field/test_nav_replay.py",
    "tests/integration/test_live_run.py",
    "tests/unit/test_live_gnss_delay.py",
    "tests/unit/test_nav_stream.py",
    "tests/unit/test_hybrid_local_compiled.py",
    "tests/contract/test_filter_contract.py",
    "tests/integration/test_full_rate.py",
    "tests/integration/test_evaluate.py",
)


def pytest_collection_modifyitems(session, config, items) -> None:
    """The files of :data:`HEAVY_FIRST` first, in its order; the rest as collected."""
    rank = {f: i for i, f in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda it: rank.get(it.nodeid.split("::")[0], len(rank)))


#: The compiled kernel modules (uavest.compiled.REGISTRY) in two halves of about equal
#: compilation time on a cold cache (shift 17 s, ut 4, manifold 3 | local 19, radar 8).
KERNEL_HALVES = (("shift", "ut", "manifold", "nav"), ("local", "radar"))


def _kernels_cold() -> bool:
    """True if a compiled kernel module (``uavest/**/_compiled*.py``) has no numba cache
    index as new as itself (a fresh clone, an edited kernel); True with ``NUMBA_CACHE_DIR``
    set (the cache is elsewhere: the warm-up then only loads it, about 2 s)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return True
    for f in (REPO_ROOT / "uavest").rglob("_compiled*.py"):
        idx = [p.stat().st_mtime for p in (f.parent / "__pycache__").glob(f"{f.stem}.*.nbi")]
        if not idx or max(idx) < f.stat().st_mtime:
            return True
    return False


def pytest_configure(config) -> None:
    """With xdist workers and a cold numba cache, the compiled kernels are compiled here,
    once, in two processes at once (half the registry each), before the workers start.
    Left to them, every worker and every command a test ran before the cache was written
    compiled the same kernels: a fresh clone's suite spent 13:46 and 1177 s of CPU where
    the same clone's warm run spent 9:22 and 894 s (``python -m pytest -q``, 2 cores)."""
    import importlib.util
    import subprocess
    import sys

    if hasattr(config, "workerinput") or not config.getoption("numprocesses", None):
        return  # a worker, or one process (it compiles what it uses, once)
    if os.environ.get("UAVEST_NUMBA") == "0" or importlib.util.find_spec("numba") is None:
        return
    if not _kernels_cold():
        return
    code = ("import sys; from uavest.apps.live import load_kernels; "
            "load_kernels(lambda s: None, sys.argv[1:])")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        p for p in (str(REPO_ROOT), os.environ.get("PYTHONPATH")) if p))
    procs = [subprocess.Popen([sys.executable, "-c", code, *half], env=env)
             for half in KERNEL_HALVES]
    for p in procs:
        p.wait()  # (a failure shows in the tests of the kernels that failed)


def compiled_kernels(loader, what: str):
    """The module of numba kernels ``loader()`` gives (e.g. ``hybrid.SHIFT_KERNELS.get``), for
    a test of a compiled path: skipped without numba or with ``UAVEST_NUMBA=0`` (.ci/run's
    second pass: the numpy paths only), failed if numba is there and the kernels were
    refused (their self-check disagreed or they did not compile: see the log)."""
    import pytest

    pytest.importorskip("numba", reason="numba not installed (the optional uavest[fast])")
    if os.environ.get("UAVEST_NUMBA") == "0":
        pytest.skip("UAVEST_NUMBA=0: the numpy paths only (.ci/run's second pass)")
    nb = loader()
    if not nb:
        pytest.fail(f"numba is installed but the {what} were refused (see the log)")
    return nb


# ----------------------------------------------------------------------------- shared logs
# The real logs written by autopilots (not by us) live beside the repository, read-only, at
# repo_root/../shared/logs; UAVEST_LOGS overrides. Tests reach them only through
# ``shared_logs_dir()`` / the ``shared_logs`` fixture / ``shared_log(name)``, which skip
# with the reason when they are absent (a source tarball, a clone without shared/).

from pathlib import Path as _Path  # noqa: E402

REPO_ROOT = _Path(__file__).resolve().parents[1]


def load_benchmark(name: str):
    """The module ``benchmarks/<name>.py`` (a script, not a package), loaded from its file."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, REPO_ROOT / "benchmarks" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def shared_logs_dir() -> _Path:
    """Where the shared logs are: ``$UAVEST_LOGS`` or ``repo_root/../shared/logs``."""
    env = os.environ.get("UAVEST_LOGS")
    return _Path(env) if env else REPO_ROOT.parent / "shared" / "logs"


def shared_sitl_dir() -> _Path:
    """Where the shared ArduCopter SITL is: ``$UAVEST_SITL`` or ``repo_root/../shared/sitl``."""
    env = os.environ.get("UAVEST_SITL")
    return _Path(env) if env else REPO_ROOT.parent / "shared" / "sitl"


def shared_log(name: str) -> _Path:
    """The path of one shared log, or skip the calling test with the reason."""
    import pytest

    p = shared_logs_dir() / name
    if not p.exists():
        pytest.skip(f"shared log {name} not found in {shared_logs_dir()} "
                    "(repo_root/../shared/logs, or set UAVEST_LOGS)")
    return p


def _shared_logs_fixture():
    import pytest

    @pytest.fixture(scope="session")
    def shared_logs() -> _Path:
        """The shared logs folder; skips the test with the reason when it is absent."""
        d = shared_logs_dir()
        if not d.is_dir():
            pytest.skip(f"shared logs not found at {d} (repo_root/../shared/logs, or set "
                        "UAVEST_LOGS)")
        return d

    return shared_logs


shared_logs = _shared_logs_fixture()


def google_decoded(path) -> dict:
    """uavest's own protobuf channels of the MCAP file ``path``, read with the ``mcap``
    reader and decoded by Google's ``protobuf`` from the schema in the file (an
    independent reader, not ours): topic -> list of messages. Skips without protobuf."""
    import pytest

    pytest.importorskip("google.protobuf")
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    from mcap.reader import make_reader

    classes: dict = {}
    got: dict = {}
    with open(path, "rb") as f:
        for schema, channel, msg in make_reader(f).iter_messages(log_time_order=False):
            if schema.encoding != "protobuf" or not schema.name.startswith("uavest."):
                continue
            cls = classes.get(schema.id)
            if cls is None:
                pool = descriptor_pool.DescriptorPool()
                for fd in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
                    pool.Add(fd)
                cls = classes[schema.id] = message_factory.GetMessageClass(
                    pool.FindMessageTypeByName(schema.name))
            got.setdefault(channel.topic, []).append(cls.FromString(msg.data))
    return got
