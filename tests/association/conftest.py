"""Association-test configuration: a report of measured error distributions.

Tests record figures with the ``report`` fixture; ``JAXTRACK_REPORT_ERRORS=1`` prints them after
the run (e.g. the LBP-vs-exact error distribution quoted in the docs).
"""

import os

import jax
import pytest

jax.config.update("jax_enable_x64", True)  # also set by tests/conftest.py; kept for safety

_REPORT: dict[str, str] = {}


@pytest.fixture
def report():
    """``report(label, text)``: keep a line for the end-of-run summary."""

    def add(label, text):
        _REPORT[label] = text

    return add


def pytest_terminal_summary(terminalreporter):
    if os.environ.get("JAXTRACK_REPORT_ERRORS") and _REPORT:
        terminalreporter.section("measured errors (tests/association)")
        for label, text in sorted(_REPORT.items()):
            terminalreporter.write_line(f"{label}: {text}")
