"""pytest set-up for both test folders (``tests/`` and the nbval run over ``notebooks/``).

The phoneme recogniser caches its output per recording (``$DUALTALKER_CACHE``, else ``~/.cache/dualtalker-lite``).
The test session gets a cache of its own, empty at the start and removed at the end, unless ``DUALTALKER_CACHE`` is
already set: whatever an earlier version or another run left in the user's cache cannot change what a test sees
(an entry of an older version is recomputed with a ``note:`` line, which tests that expect a silent stderr would
read), and the tests never write into the user's home. The notebooks' kernels inherit the variable.

Hypothesis's profiles are registered here, before its plugin reads ``--hypothesis-profile``: ``ci`` (the default,
derandomized) and ``fuzz`` (``make fuzz``).
"""
import os
import shutil
import tempfile

_OWN_CACHE = None

# Hypothesis profiles (tests/test_fuzz.py and the other property tests). "ci", the default: derandomized, so every
# run of the suite tries the same examples (deterministic and cheap); "fuzz" (`make fuzz`): random examples, many of
# them, failures kept in .hypothesis/ and replayed first on the next run.
try:
    from hypothesis import HealthCheck, settings as _hypothesis_settings

    _hypothesis_settings.register_profile("ci", derandomize=True, max_examples=12, deadline=None, database=None,
                                          suppress_health_check=[HealthCheck.too_slow])
    _hypothesis_settings.register_profile("fuzz", max_examples=300, deadline=None,
                                          suppress_health_check=[HealthCheck.too_slow])
    _hypothesis_settings.load_profile("ci")
except ImportError:  # the [dev] extra is not installed: the property tests skip themselves
    pass


def pytest_configure(config):
    global _OWN_CACHE
    if "DUALTALKER_CACHE" not in os.environ:
        _OWN_CACHE = tempfile.mkdtemp(prefix="dualtalker-test-cache-")
        os.environ["DUALTALKER_CACHE"] = _OWN_CACHE


def pytest_unconfigure(config):
    if _OWN_CACHE is not None:
        shutil.rmtree(_OWN_CACHE, ignore_errors=True)
        os.environ.pop("DUALTALKER_CACHE", None)
