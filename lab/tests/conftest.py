"""The product suite's shared smoke runs (tests/conftest.py), which some lab tests read: `pytest lab` does not load
that conftest on its own."""

from tests.conftest import averaged_run, every_chunk_run  # noqa: F401 (fixtures, found by name)
