"""The suite's side of ``GSJAX_COMPILE_LOG`` (:mod:`gsjax.app.runtime.compile_log`): each line names the test that
compiled the program (a module fixture's compilations go to the first test that uses it). Loaded by
``tests/conftest.py``.""" 
from __future__ import annotations

import pytest

from gsjax.app.runtime import compile_log


def pytest_configure(config):
    log = compile_log.install_from_env()
    if log is not None:
        log.doing = "(collection)"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    log = compile_log.install_from_env()
    if log is not None:
        log.doing = item.nodeid
    yield
